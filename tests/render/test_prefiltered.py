"""Prefiltered environment lighting (render.prefiltered) on cases whose answer is known in closed form,
and the environment head's fit (train.environment_fit) against the reference's albedo."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from mtlx2neural.model import proxy
from mtlx2neural.model.neural_material import NeuralMaterial
from mtlx2neural.render.geometry import OrthographicCamera, Sphere
from mtlx2neural.render.lighting import EnvironmentMap, uv_to_direction
from mtlx2neural.render.prefiltered import (
    LATTICE_FINEST_WIDTH,
    EnvironmentPyramid,
    PrefilteredEnvironment,
    lobe_means,
    prefiltered_radiance,
    row_solid_angles,
)
from mtlx2neural.render.renderer import render_scene

# A linear environment L(d) = A + G . d (world directions, y up), everywhere positive.
A, G = 1.0, torch.tensor([0.3, 0.5, -0.2])


def linear_environment(height: int = 64, width: int = 128) -> EnvironmentMap:
    v, u = torch.meshgrid((torch.arange(height) + 0.5) / height, (torch.arange(width) + 0.5) / width, indexing="ij")
    d = uv_to_direction(torch.stack([u, v], -1).reshape(-1, 2))
    img = (A + d @ G)[:, None].expand(-1, 3) * torch.tensor([1.0, 0.8, 0.6])
    return EnvironmentMap(img.reshape(height, width, 3).numpy())


def frames(normals: torch.Tensor):
    """(tangent, bitangent, normal) [N,3] each, orthonormal, around unit ``normals``."""
    helper = torch.where(normals[:, :1].abs() < 0.9, torch.tensor([[1.0, 0.0, 0.0]]), torch.tensor([[0.0, 1.0, 0.0]]))
    t = torch.nn.functional.normalize(helper - normals * (helper * normals).sum(-1, keepdim=True), dim=-1)
    return t, torch.linalg.cross(normals, t, dim=-1), normals


def params(n: int, alpha: float = 0.3, slope_diff=(0.0, 0.0)) -> proxy.ProxyParams:
    return proxy.ProxyParams(torch.full((n, 2), alpha), torch.zeros(n, 1), torch.zeros(n, 2),
                             torch.tensor([slope_diff]).expand(n, 2), torch.full((n, 1), 0.5))


NORMALS = torch.nn.functional.normalize(torch.tensor([[0.0, 1.0, 0.0], [0.6, 0.3, 0.2], [-0.2, -0.1, 0.9],
                                                      [0.0, -1.0, 0.1]]), dim=-1)


def test_pyramid_levels_keep_the_maps_integral():
    sky = EnvironmentMap.sky()
    pyramid = EnvironmentPyramid(sky)
    assert [tuple(lv.shape[:2]) for lv in pyramid.levels] == [(64, 128), (32, 64), (16, 32), (8, 16), (4, 8)]

    def integral(img):  # exact per row: the map is piecewise constant per texel
        return (img * row_solid_angles(img.shape[0])[:, None, None]).sum((0, 1)) * (2 * math.pi / img.shape[1])

    first = integral(pyramid.levels[0])
    for level in pyramid.levels[1:]:
        # Each coarse texel is the solid-angle weighted mean of the four below: the integral is kept
        # to float32 rounding.
        torch.testing.assert_close(integral(level), first, rtol=1e-5, atol=0.0)


def test_a_lambertian_lobe_is_the_clamped_cosines_projection():
    """A cosine lobe about the normal averages a linear environment to A + (2/3) G . n (the clamped
    cosine's projection onto the constant and linear spherical harmonics, normalised by pi); so does a
    tilted lobe about its axis."""
    env = EnvironmentPyramid(linear_environment())
    n = NORMALS.shape[0]
    wi = torch.nn.functional.normalize(torch.tensor([[0.3, 0.2, 0.93]]).expand(n, 3), dim=-1)
    basis = frames(NORMALS)
    for slope in ((0.0, 0.0), (0.4, -0.3)):
        e = lobe_means(env, basis, wi, params(n, slope_diff=slope))
        axis = torch.nn.functional.normalize(torch.tensor([-slope[0], -slope[1], 1.0]), dim=0)
        world = axis[0] * basis[0] + axis[1] * basis[1] + axis[2] * basis[2]
        expected = (A + (2.0 / 3.0) * world @ G)[:, None] * torch.tensor([1.0, 0.8, 0.6])
        # 5e-3: the irradiance map's direct quadrature over 64 x 128 texels cuts the clamped cosine's kink at
        # texel edges, and its lookup is bilinear between texel centres (measured 2.5e-3).
        torch.testing.assert_close(e[:, 2], expected, rtol=5e-3, atol=0.0)


def test_a_near_mirror_lobe_reads_the_reflected_direction():
    env = EnvironmentPyramid(linear_environment())
    n = NORMALS.shape[0]
    wi = torch.nn.functional.normalize(torch.tensor([[0.4, -0.3, 0.8]]).expand(n, 3), dim=-1)
    basis = frames(NORMALS)
    e = lobe_means(env, basis, wi, params(n, alpha=1e-3))
    mirror = wi * torch.tensor([-1.0, -1.0, 1.0])
    world = mirror[:, :1] * basis[0] + mirror[:, 1:2] * basis[1] + mirror[:, 2:] * basis[2]
    expected = (A + world @ G)[:, None] * torch.tensor([1.0, 0.8, 0.6])
    # 0.5 %: the lobe is ~0.1 degrees wide, read at level 0 bilinearly (a linear function but for
    # the lat-long map's curvature within a texel of 2.8 degrees). Measured 0.1 %. The sharp lobe (about the
    # same mean microfacet normal, here the normal) reads the same direction.
    torch.testing.assert_close(e[:, 1], expected, rtol=5e-3, atol=0.0)
    torch.testing.assert_close(e[:, 0], expected, rtol=5e-3, atol=0.0)


def test_the_specular_lattice_reads_no_finer_than_64_texels_and_the_sharp_lobe_does():
    """A near-mirror specular lobe aimed at a one-texel source reads it at the level 64 texels wide
    (LATTICE_FINEST_WIDTH, what the MaterialX node's two-level lookups read), the sharp lobe at its own finer level."""
    img = np.full((128, 256, 3), 0.5, np.float32)
    img[40, 100] = 1000.0
    env = EnvironmentPyramid(EnvironmentMap(img))
    assert env.finest_for_width(LATTICE_FINEST_WIDTH) == 2 and env.levels[2].shape[1] == 64
    source = uv_to_direction(torch.tensor([[100.5 / 256, 40.5 / 128]]))
    normal = torch.nn.functional.normalize(source + torch.tensor([[0.0, 1.0, 0.0]]), dim=-1)
    basis = frames(normal)
    world_wi = 2 * (source * normal).sum(-1, keepdim=True) * normal - source  # the source's mirror image
    wi = torch.stack([(world_wi * v).sum(-1) for v in basis], -1)
    e = lobe_means(env, basis, wi, params(1, alpha=1e-3))
    level2 = env.lookup(source, torch.tensor([2.0]))
    sharp = env.lookup(source, env.level_of(source, torch.tensor([proxy.SHARP_SOLID_ANGLE])))
    assert sharp[0, 0] > 2.0 * level2[0, 0]  # the sharp lobe's own level keeps more of the source
    # 2 %: the lobe's 16 lattice directions spread over ~0.1 degrees, a fiftieth of a level-2 texel.
    torch.testing.assert_close(e[:, 1], level2, rtol=0.02, atol=0.0)
    torch.testing.assert_close(e[:, 0], sharp, rtol=0.02, atol=0.0)


def test_a_constant_environment_gives_the_heads_reflectance():
    """L_out = c_spec E_spec + c_diff E_diff with E = L everywhere: (c_spec + c_diff) L, for any
    networks (a seeded random model with an environment head)."""
    torch.manual_seed(3)
    model = NeuralMaterial((4, 4), in_dim=2, latent_dim=8, frames=2, decoder="2x16", environment_head=True)
    env = EnvironmentPyramid(EnvironmentMap(np.full((32, 64, 3), 2.5, np.float32)))
    n = NORMALS.shape[0]
    wi = torch.nn.functional.normalize(torch.rand(n, 3) + torch.tensor([0.0, 0.0, 0.3]), dim=-1)
    out = prefiltered_radiance(model, env, frames(NORMALS), wi)
    _, _, c = model.environment_lobes(wi)
    # 1e-3: E_spec is exact (every lookup reads 2.5); E_diff comes from the map's order-2 harmonics, whose
    # bands 1-2 integrate a constant map to zero only up to the midpoint rule over its 32 rows (measured 2.8e-4).
    torch.testing.assert_close(out, 2.5 * c.sum(1), rtol=1e-3, atol=0.0)


def test_materials_without_a_head_are_sampled_as_the_plain_map():
    """The reference (no environment head) renders the same under the prefiltered light as under its map."""
    torch.manual_seed(0)
    model = NeuralMaterial((4, 4), in_dim=2, latent_dim=8, frames=2, decoder="2x16")
    sky = EnvironmentMap.sky()
    a = render_scene(model, Sphere(), OrthographicCamera(30.0, 20.0), [sky], 16, 2, sampler=model)
    b = render_scene(model, Sphere(), OrthographicCamera(30.0, 20.0), [PrefilteredEnvironment(sky)], 16, 2,
                     sampler=model)
    np.testing.assert_array_equal(a, b)


@pytest.mark.slow
def test_the_environment_head_fits_the_references_albedo():
    """A short training of a two-lobe material (a coat over a diffuse base): the lobes' reflectances add up
    to the reference's directional albedo."""
    from materials import layered_spheres_material

    from mtlx2neural.train.config import preset
    from mtlx2neural.train.trainer import Trainer

    ref, stack = layered_spheres_material("CarPaint")
    cfg = preset("fast", iterations=300, batch=1024, seed=1, environment_fraction=1.0, probe_every=0)
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        model = Trainer(ref, stack, cfg, tmp).run(progress=False)
    wi = torch.tensor([[math.sqrt(1 - c * c), 0.0, c] for c in (0.95, 0.7, 0.4, 0.15)])
    _, _, c = model.environment_lobes(wi)
    albedo = ref.albedo(wi, samples=20000)
    luma = torch.tensor([0.2126, 0.7152, 0.0722])
    ratio = (c.sum(1) @ luma) / (albedo @ luma)
    # 20 %: 300 steps of one-sample targets (relative squared error about 1 per row at the end) and the
    # latents of a 300-step BRDF; measured 0.90-1.12 in luminance at seed 1.
    assert torch.all((ratio > 0.8) & (ratio < 1.2)), ratio.tolist()
    assert torch.all(c.sum(-1) > 0)  # all three lobes carry light: the sharp one the coat's peak


def test_rows_drawn_ahead_keep_every_material_in_every_step(monkeypatch):
    """Drawing the environment fit's rows several steps at a time (environment_fit.AHEAD): step k takes the
    k-th block of ``per`` rows of every material, none twice."""
    from mtlx2neural.train import environment_fit

    def rows(trainer, batch):  # row i of material m holds (m, i)
        ids = torch.stack([torch.full((batch,), float(trainer)), torch.arange(batch, dtype=torch.float32)], -1)
        return ids, ids, ids

    monkeypatch.setattr(environment_fit, "_rows", rows)
    steps = environment_fit._rows_ahead([0, 1, 2], per=4, steps=3)
    assert len(steps) == 3
    for k, (lat, _, _) in enumerate(steps):
        assert lat[:, 0].tolist() == [0.0] * 4 + [1.0] * 4 + [2.0] * 4
        assert lat[:, 1].tolist() == list(range(4 * k, 4 * k + 4)) * 3


def test_the_irradiance_map_is_dark_where_no_light_reaches():
    """A surface facing away from the only light (a patch of sky around one direction) receives nothing; the
    map's order-2 harmonics would give it up to 6 % of the lit side's irradiance (their ringing)."""
    h, w = 64, 128
    v, u = torch.meshgrid((torch.arange(h) + 0.5) / h, (torch.arange(w) + 0.5) / w, indexing="ij")
    d = uv_to_direction(torch.stack([u, v], -1).reshape(-1, 2))
    sun = torch.nn.functional.normalize(torch.tensor([0.3, 0.8, 0.2]), dim=0)
    img = torch.where((d @ sun > 0.995)[:, None], torch.tensor([50.0, 40.0, 30.0]), torch.zeros(3))
    env = EnvironmentPyramid(EnvironmentMap(img.reshape(h, w, 3).numpy()))
    perp = torch.nn.functional.normalize(torch.linalg.cross(sun, torch.tensor([0.0, 0.0, 1.0])), dim=0)
    side = math.cos(math.radians(100)) * sun + math.sin(math.radians(100)) * perp  # 100 degrees from the sun
    lit, away, side = env.irradiance(torch.stack([sun, -sun, side]))
    # the patch's irradiance / pi on the lit side, by direct sum over its texels
    area = (row_solid_angles(h)[:, None] * (2 * math.pi / w)).expand(h, w).reshape(-1)
    expected = (img * ((d @ sun).clamp_min(0) * area)[:, None]).sum(0) / math.pi
    # 2 %: the lookup is bilinear between the irradiance map's texel centres, which lie up to 1.4 degrees
    # from the sun's direction (measured 0.3 %)
    torch.testing.assert_close(lit, expected, rtol=0.02, atol=0.0)
    # the patch is 5.7 degrees in radius: 100 degrees from it (side) and opposite it, nothing (the
    # harmonics give 0.024 and 0.058 of the lit side there); 1e-3: bilinear weights of texels nearer the sun
    assert float(away.max()) < 1e-3 * float(lit.max()) and float(side.max()) < 1e-3 * float(lit.max())


class _PlainTargets:
    """``train.targets``' interface for a uniform material: the reference itself, no footprint or cone."""

    def __init__(self, reference):
        self.reference = reference

    def lobe_uv(self, uv):
        return uv

    def brdf(self, wi, wo, uv, level, angle):
        return self.reference.eval(wi, wo)


def test_the_three_lobes_targets_add_up_to_the_albedo():
    """The environment fit's one-sample targets (a third of the directions from the learned sampler, the
    reference's sampler and the sharp lobe each; the reflectance split by responsibilities in the three-lobe
    mixture, the sharp lobe's kept where f peaks inside its cone) are unbiased: their sum averages to the
    reference's directional albedo, and a clear coat's sharp lobe takes a share of it that a rough dielectric's
    does not."""
    from materials import reference_of, standard_surface

    from mtlx2neural.train.environment_fit import lobe_targets

    torch.manual_seed(5)
    model = NeuralMaterial((4, 4), in_dim=2, latent_dim=8, frames=2, decoder="2x16", environment_head=True)
    with torch.no_grad():  # a sampler centred on the mirror direction (raw outputs 0: slopes 0, alpha 0.5, 50/50)
        model.sampler.net[-1].weight.zero_()
        model.sampler.net[-1].bias.zero_()
    coat = reference_of(standard_surface("M", "SR", base_color=(0.5, 0.1, 0.1), coat=1.0, coat_roughness=0.05))
    rough = reference_of(standard_surface("M", "SR", base_color=(0.2, 0.4, 0.6), specular_roughness=0.5))
    n = 60_000
    shares = {}
    for label, ref in (("coat", coat), ("rough", rough)):
        wi = torch.nn.functional.normalize(torch.tensor([[0.5, 0.1, 0.8]]), dim=-1).expand(n, 3)
        uv = torch.rand(n, 2, generator=torch.Generator().manual_seed(1))
        with torch.no_grad():
            lat = model.latents.fetch(uv, torch.zeros(n, dtype=torch.long))
            y = lobe_targets(ref, _PlainTargets(ref), model, lat, uv, None, wi, torch.Generator().manual_seed(2))
        assert y.shape == (n, 3, 3) and bool((y >= 0).all())
        albedo = ref.albedo(wi[:1], samples=40_000)[0]
        # 4 %: 60000 one-sample estimates of a lobed integrand (their relative standard error here is about
        # 1 %) against a 40000-sample albedo
        torch.testing.assert_close(y.mean(0).sum(0), albedo.float(), rtol=0.04, atol=0.0)
        shares[label] = float(y.mean(0)[0].sum() / y.mean(0).sum())
    # measured 0.17 and 0.0002: the coat's near-mirror peak, and next to nothing of a rough lobe, whose f is as
    # high on the ring 8 sharp alphas out as inside the sharp cone (by responsibilities alone the rough lobe
    # gave 0.011, which lit a sun glint on a rough plastic)
    assert shares["coat"] > 0.1 and shares["rough"] < 0.003, shares


class _HeadFit:
    """What ``fit_environment_head`` reads of a trainer: a fresh model with a mirror-centred sampler (as above)
    and a uniform reference's targets at level 0."""

    def __init__(self, reference, seed: int):
        torch.manual_seed(seed)
        self.model = NeuralMaterial((4, 4), in_dim=2, latent_dim=8, frames=2, decoder="2x16", environment_head=True)
        with torch.no_grad():
            self.model.sampler.net[-1].weight.zero_()
            self.model.sampler.net[-1].bias.zero_()
        self.ref, self.targets = reference, _PlainTargets(reference)
        self.targets.levels = lambda n, dev: torch.zeros(n, dtype=torch.long, device=dev)
        self.device, self.gen, self.tiles = "cpu", torch.Generator().manual_seed(seed), None

    def surface_uv(self, n: int) -> torch.Tensor:
        from mtlx2neural.train.udim import draw_uv

        return draw_uv(n, None, self.gen)


def test_lobes_that_carry_almost_nothing_are_silenced():
    """After the fit, a material whose sharp-lobe targets carry under SHARP_MIN_SHARE of its reflectance (a rough
    dielectric: 0.0002 above) gets the legacy head's silent sharp lobe (0 in FP16), which the fit could only
    approach; a clear coat (0.17) keeps its own; a shared head keeps it when any of its materials needs it. A
    material that reflects nothing (thin-walled subsurface: all its light goes through) gets a silent head."""
    from materials import reference_of, standard_surface

    from mtlx2neural.formats.weights import SILENT_LOGIT
    from mtlx2neural.train.environment_fit import (
        SHARP_MIN_SHARE,
        fit_environment_head,
        wake_silent_lobes,
    )

    coat = reference_of(standard_surface("M", "SR", base_color=(0.5, 0.1, 0.1), coat=1.0, coat_roughness=0.05))
    rough = reference_of(standard_surface("M", "SR", base_color=(0.2, 0.4, 0.6), specular_roughness=0.5))
    black = reference_of(standard_surface("M", "SR", specular=0.0, thin_walled=True, subsurface=1.0))
    wi = torch.nn.functional.normalize(torch.tensor([[0.5, 0.1, 0.8], [0.0, 0.3, 0.4]]), dim=-1)
    for group, silent in (([rough], ["sharp"]), ([coat], []), ([rough, coat], []),
                          ([black], ["sharp", "specular", "diffuse"]), ([black, rough], ["sharp"])):
        fits = [_HeadFit(ref, seed=7) for ref in group]
        for f in fits[1:]:  # one shared decoder, as train.shared fits it
            f.model.decoder = fits[0].model.decoder
        history = fit_environment_head(fits if len(fits) > 1 else fits[0], steps=60, batch=512)
        last = history[-1]
        assert last["silent_lobes"] == silent, last
        if group != [black]:
            assert (last["sharp_share"] >= SHARP_MIN_SHARE) == ("sharp" not in silent), last
        with torch.no_grad():
            _, _, c = fits[-1].model.environment_lobes(wi, torch.rand(2, 2))
        bias = fits[0].model.decoder.environment[-1].bias.view(3, 3)
        for k, name in enumerate(("sharp", "specular", "diffuse")):
            if name in silent:  # exp(-103): 0 in FP16
                assert bool((c[:, k] < 1e-40).all()) and bool((bias[k] == SILENT_LOGIT).all()), name
            else:
                assert bool((c[:, k].sum(-1) > 0).all()) and bool((bias[k] > SILENT_LOGIT).all()), name
    # a silenced head wakes before another fit: the lobes start again from live outputs
    head = fits[0].model.decoder.environment
    wake_silent_lobes(head)
    assert bool((head[-1].bias > SILENT_LOGIT).all())


def test_the_head_goes_over_each_drawn_batch_several_times(monkeypatch):
    """The fit draws ``steps`` batches of the reference's targets (the expensive part) and takes PASSES Adam steps
    on each, a chunk at a time: the head was under-fitted at one step per batch (docs/history)."""
    from materials import reference_of, standard_surface

    from mtlx2neural.train import environment_fit

    drawn = []
    rows_ahead = environment_fit._rows_ahead
    monkeypatch.setattr(environment_fit, "_rows_ahead",
                        lambda *a: drawn.append(a[2]) or rows_ahead(*a))
    fit = _HeadFit(reference_of(standard_surface("M", "SR", specular_roughness=0.5)), seed=8)
    history = environment_fit.fit_environment_head(fit, steps=60, batch=256)
    assert sum(drawn) == 60 and len(drawn) == 3  # chunks of AHEAD = 25 batches
    assert history[-1]["step"] == 60 * environment_fit.PASSES


def test_a_legacy_heads_sharp_lobe_wakes_before_it_is_fitted_again():
    """A head upgraded from one without the sharp lobe gives it exp(-103): no gradient reaches it, so a fit
    (the universal networks' fine-tune) first starts it from the specular lobe's outputs, at a tenth."""
    from mtlx2neural.formats.weights import SILENT_LOGIT
    from mtlx2neural.train.environment_fit import wake_silent_lobes

    torch.manual_seed(6)
    model = NeuralMaterial((4, 4), in_dim=2, latent_dim=8, frames=2, decoder="2x16", environment_head=True)
    last = model.decoder.environment[-1]
    assert not wake_silent_lobes(model.decoder.environment)  # a head of today: left alone
    with torch.no_grad():
        last.bias[:3] = SILENT_LOGIT
    assert wake_silent_lobes(model.decoder.environment)
    wi = torch.nn.functional.normalize(torch.rand(32, 3) + torch.tensor([0.0, 0.0, 0.5]), dim=-1)
    with torch.no_grad():
        _, _, c = model.environment_lobes(wi, torch.rand(32, 2))
    torch.testing.assert_close(c[:, 0], c[:, 1] / 10.0, rtol=1e-5, atol=0.0)
