"""The energy estimators' random points: one scrambled Sobol sequence, shifted per row."""

from __future__ import annotations

import math

import torch
from materials import layered_spheres_material

from mtlx2neural.contract import ShadingPoint
from mtlx2neural.textures.footprint_albedo import mixture_albedo, row_shifted_sobol


def test_each_row_is_the_sequence_shifted_modulo_one_by_its_own_vector():
    rows, samples, dims = 5, 16, 3
    u = row_shifted_sobol(rows, samples, dims, seed=3).view(rows, samples, dims)
    sobol = torch.quasirandom.SobolEngine(dims, scramble=True, seed=3).draw(samples)
    assert bool(((u >= 0) & (u < 1)).all())
    shift = torch.frac(u - sobol[None] + 1.0)  # each row's offset, the same for every point up to the wrap
    spread = torch.minimum((shift - shift[:, :1]).abs(), 1 - (shift - shift[:, :1]).abs())
    assert float(spread.max()) < 1e-5
    assert float(torch.cdist(shift[:, 0], shift[:, 0]).add(torch.eye(rows)).min()) > 1e-3  # rows differ
    assert torch.equal(u, row_shifted_sobol(rows, samples, dims, seed=3).view(rows, samples, dims))


def test_a_sum_over_rows_averages_their_errors_out():
    """The CarPaint's albedo at 60 degrees from the normal, estimated by the mixture (the reference standing in for
    the model) over 64 identical rows of 24 directions, at six seeds. With one shared sequence every row repeats one
    error, so the rows' mean varies by seed as much as one row does; with a shift per row it varies about 1 / sqrt(64)
    as much. Bound: half of one row's spread (measured: 0.15 of it)."""
    ref, _ = layered_spheres_material("CarPaint")
    n = 64
    wi = torch.tensor([[math.sin(math.radians(60.0)), 0.0, math.cos(math.radians(60.0))]]).expand(n, 3)
    at = ShadingPoint(uv=torch.full((n, 2), 0.5))
    means = torch.stack([mixture_albedo(ref, ref, wi, at, at, samples=24, seed=s).mean(0) for s in range(6)])
    single = torch.stack([mixture_albedo(ref, ref, wi[:1], ShadingPoint(uv=torch.full((1, 2), 0.5)),
                                         ShadingPoint(uv=torch.full((1, 2), 0.5)), samples=24, seed=s)[0]
                          for s in range(6)])
    assert float(means.std(0).mean()) < 0.5 * float(single.std(0).mean()), (means, single)


class _UniformLambert:
    """A Lambertian of albedo ``rho`` (grey) that samples the hemisphere uniformly (pdf 1 / 2 pi), a poor match."""

    def __init__(self, rho: float):
        self.rho = rho

    def eval(self, wi, wo, at=None):
        return (self.rho / math.pi * wo[:, 2].clamp(min=0.0))[:, None].expand(-1, 3)

    def pdf(self, wi, wo, at=None):
        return (wo[:, 2] > 0).to(wo.dtype) / (2 * math.pi)

    def sample(self, wi, u, at=None):
        z, phi = u[:, 0], 2 * math.pi * u[:, 1]
        r = (1 - z * z).clamp(min=0.0).sqrt()
        wo = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)
        return wo, None, self.pdf(wi, wo)


class _NormalLobe(_UniformLambert):
    """Samples a narrow lobe about the normal (pdf (n + 1) / 2 pi cos^n), the reference's strategy stand-in."""

    N = 20.0

    def pdf(self, wi, wo, at=None):
        return (self.N + 1) / (2 * math.pi) * wo[:, 2].clamp(min=0.0) ** self.N

    def sample(self, wi, u, at=None):
        z, phi = u[:, 0] ** (1 / (self.N + 1)), 2 * math.pi * u[:, 1]
        r = (1 - z * z).clamp(min=0.0).sqrt()
        wo = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)
        return wo, None, self.pdf(wi, wo)


def test_the_mixture_is_unbiased_when_the_samples_do_not_split_evenly_between_its_strategies():
    """A Lambertian of albedo 0.6 whose own sampler is uniform, beside a narrow lobe standing in for the reference's
    sampler and the cosine, at 4 and 5 directions per row (2 / 1 / 1 and 2 / 2 / 1 between the strategies), over
    4096 rows: the mean is the albedo. Weighing the three pdfs equally reads 0.622 at 4 and 0.564 at 5 (0.599 at 3).
    Tolerance 1 %: the estimate's standard error over 4096 rows is about 0.2 %."""
    model, lobe = _UniformLambert(0.6), _NormalLobe(0.6)
    n = 4096
    wi = torch.tensor([[0.0, 0.0, 1.0]]).expand(n, 3)
    at = ShadingPoint(uv=torch.full((n, 2), 0.5))
    for samples in (4, 5):
        albedo = mixture_albedo(model, lobe, wi, at, at, samples=samples, seed=1)
        assert abs(float(albedo.mean()) - 0.6) < 0.006, (samples, float(albedo.mean()))


def test_a_footprint_without_surface_keeps_the_plain_mean_as_the_training_targets_do():
    """A cut-out whose surface is the left half of the texture: at the finest level of a 2 x 2 grid (footprint sigma a
    quarter of the texture) rows centred on the right half have footprints whose points all miss the surface. Their
    reference albedo is the points' plain mean (the uniform CarPaint's albedo, within 3 %: its Monte Carlo error), as
    ``footprint_targets`` trains them, not 0; rows on the left read the same albedo through their covered points."""
    from mtlx2neural.textures.footprint_albedo import reference_footprint_albedo

    ref, _ = layered_spheres_material("CarPaint")
    n = 32
    wi = torch.tensor([[0.0, 0.0, 1.0]]).expand(n, 3)
    uv = torch.stack([torch.where(torch.arange(n) < n // 2, 0.25, 0.75), torch.full((n,), 0.5)], -1)

    def left_half(points):
        return (torch.frac(points[:, 0]) < 0.5).float()

    def albedo(coverage):
        return reference_footprint_albedo(ref, wi, uv, 0, (2, 2), points=1, samples=64, seed=0,
                                          generator=torch.Generator().manual_seed(0), coverage=coverage)

    plain, cut = albedo(None), albedo(left_half)
    assert float(plain.min()) > 0.05
    assert torch.allclose(cut, plain, rtol=0.03), (cut, plain)
