"""Mollified training targets (``train.mollify``): the MIS cone mean against brute force, its uv and
parameter paths, the lobe directions, and what the floor buys in training (grazing energy)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

import mtlx2neural as m2n
from mtlx2neural.contract import ShadingPoint
from mtlx2neural.textures.parameter_stack import build_parameter_stack
from mtlx2neural.train.config import preset
from mtlx2neural.train.directions import cone_jitter
from mtlx2neural.train.mollify import cone_mean, lobe_directions
from mtlx2neural.train.trainer import Trainer

SAMPLE = Path(__file__).resolve().parents[2] / "samples" / "layered_spheres.usda"


@pytest.fixture(scope="module")
def carpaint():
    return m2n.load_reference(SAMPLE, "/World/Looks/CarPaint")


def _dir(elevation_deg: float, azimuth_deg: float = 0.0) -> torch.Tensor:
    th, ph = math.radians(90 - elevation_deg), math.radians(azimuth_deg)
    return torch.tensor([[math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)]])


def test_cone_mean_matches_brute_force_on_a_sharp_coat(carpaint):
    """The CarPaint's coat (roughness 0.08) at wi 20 degrees above the horizon, a 2-degree cone centred
    on the mirror direction and 1 and 4 degrees off it. Brute force: 400k directions uniform in the
    cone (the lobe covers a few % of it, so its mean has ~2 % standard error); the MIS estimate is
    averaged over 2048 draws of 4 pairs (its error is well below 1 %). 6 % relative covers both."""
    angle = math.radians(2.0)
    wi = _dir(20.0)
    g = torch.Generator().manual_seed(0)
    for off in (0.0, 1.0, 4.0):
        wo = _dir(20.0 + off, 180.0)
        brute = carpaint.eval(wi.expand(400_000, 3), cone_jitter(wo, angle, 400_000, g)).mean(0)
        est = cone_mean(carpaint, wi.expand(2048, 3), wo.expand(2048, 3), angle, 4, g).mean(0)
        assert torch.allclose(est, brute, rtol=0.06, atol=1e-3), (off, est, brute)
    # At the mirror direction the mean over the cone is far below the spike's peak but far above the
    # base: the lobe is kept, widened
    peak = carpaint.eval(wi, _dir(20.0, 180.0))[0]
    assert float(est.mean()) < float(peak.mean())
    assert cone_mean(carpaint, wi, wo, 0.0).equal(carpaint.eval(wi, wo))  # angle 0: the value itself


def test_cone_mean_reads_a_textured_material_once_per_point():
    """A ShadingPoint's ``uv`` is turned into parameters once (``parameters_at``): same random numbers,
    same result as passing those parameters; and the result is finite, non-negative, and 0 for a cone below the horizon."""
    doc = Path(__file__).resolve().parents[2] / "samples" / "textured" / "ceramic_and_metal.usda"
    if not doc.exists():
        import subprocess
        import sys

        subprocess.run([sys.executable, str(doc.parents[1] / "make_textured_sample.py")], check=True)
    ref = m2n.load_reference(doc, "/World/Looks/GlazedCeramic")
    g = torch.Generator().manual_seed(1)
    n = 512
    wi = torch.nn.functional.normalize(torch.rand(n, 3, generator=g) * torch.tensor([2.0, 2.0, 1.0])
                                       - torch.tensor([1.0, 1.0, 0.0]), dim=-1)
    wo = wi * torch.tensor([-1.0, -1.0, 1.0])
    uv = torch.rand(n, 2, generator=g)
    a = cone_mean(ref, wi, wo, math.radians(2.0), 1, torch.Generator().manual_seed(5), ShadingPoint(uv=uv))
    b = cone_mean(ref, wi, wo, math.radians(2.0), 1, torch.Generator().manual_seed(5),
                  ShadingPoint(params=ref.parameters_at(uv)))
    assert a.equal(b)
    assert bool(torch.isfinite(a).all()) and bool((a >= 0).all())
    # a cone wholly below the horizon (wo.z <= -0.1, more than 5 degrees down) sees nothing
    down = torch.nn.functional.normalize(torch.cat([wo[:, :2], -wo[:, 2:].clamp_min(0.1)], -1), dim=-1)
    assert float(cone_mean(ref, wi, down, math.radians(2.0), 1, g, ShadingPoint(uv=uv)).abs().max()) == 0.0


class _Contract:
    """The Material contract's eval/sample/pdf of a reference, nothing more (no fast paths)."""

    def __init__(self, reference):
        self.reference = reference

    def eval(self, wi, wo, at=None):
        return self.reference.eval(wi, wo, at)

    def pdf(self, wi, wo, at=None):
        return self.reference.pdf(wi, wo, at)

    def sample(self, wi, u, at=None):
        return self.reference.sample(wi, u, at)


def test_cone_mean_fast_path_equals_the_contract(carpaint):
    """cone_mean takes the reference's value and density at both directions of a pair from one evaluation
    (``sample_and_eval_pdf``; also ``eval_pdf``, ``sample(..., with_value=True)``): bit for bit what separate
    eval and pdf calls give, so the estimate is the same."""
    g = torch.Generator().manual_seed(3)
    wi = torch.nn.functional.normalize(torch.randn(4096, 3, generator=g).abs() + torch.tensor([0.0, 0.0, 0.2]), dim=-1)
    wo = wi * torch.tensor([-1.0, -1.0, 1.0]) + 0.05 * torch.randn(4096, 3, generator=g)
    fast = cone_mean(carpaint, wi, wo, math.radians(2.0), 2, torch.Generator().manual_seed(4))
    plain = cone_mean(_Contract(carpaint), wi, wo, math.radians(2.0), 2, torch.Generator().manual_seed(4))
    assert float(fast.mean()) > 0.01 and fast.equal(plain)
    f, pdf = carpaint.eval_pdf(wi, wo)
    assert f.equal(carpaint.eval(wi, wo)) and pdf.equal(carpaint.pdf(wi, wo))
    u = torch.rand(4096, 2, generator=g)
    w, value, density = carpaint.sample(wi, u, with_value=True)
    assert value.equal(carpaint.eval(wi, w)) and density.equal(carpaint.pdf(wi, w))
    # Both at once, from one evaluation of the lobes: the same tensors as the two calls.
    (w2, value2, density2), (f2, pdf2) = carpaint.sample_and_eval_pdf(wi, u, wo)
    assert w2.equal(w) and value2.equal(value) and density2.equal(density) and f2.equal(f) and pdf2.equal(pdf)


def test_lobe_directions_gather_around_the_coat(carpaint):
    """Directions from the reference's sampler spread over the cone: most lie within a few degrees of
    the mirror direction (the coat and the metal's roughness-0.3 lobe share the energy), all above the
    horizon where ``ok``."""
    n = 4096
    wi = _dir(30.0).expand(n, 3)
    wo, ok = lobe_directions(carpaint, wi, math.radians(2.0), torch.Generator().manual_seed(2))
    assert float(ok.float().mean()) > 0.95 and bool((wo[ok][:, 2] > 0).all())
    mirror = _dir(30.0, 180.0)
    near = (wo[ok] @ mirror.T).squeeze(-1) > math.cos(math.radians(10.0))
    assert float(near.float().mean()) > 0.3


def _grazing_albedo(model, ref, elevation: float, n: int = 100_000) -> tuple[float, float]:
    """(neural, reference) directional albedo at ``elevation`` degrees, grey average. The neural one
    draws ``wo`` from an even mixture of the uniform hemisphere and the reference's sampler and divides
    by the mixture's density: uniform directions alone hit a 1-degree coat lobe about 15 times in
    100k, so their estimate moved by a quarter from one model to the next."""
    g = torch.Generator().manual_seed(4)
    wi = _dir(elevation).expand(n, 3)
    u = torch.rand(n, 2, generator=g)
    z = u[:, 1]
    r = (1 - z * z).clamp_min(0).sqrt()
    uniform = torch.stack([r * torch.cos(2 * math.pi * u[:, 0]), r * torch.sin(2 * math.pi * u[:, 0]), z], -1)
    with torch.no_grad():
        lobe, w, _ = ref.sample(wi, torch.rand(n, 2, generator=g))
        wo = torch.where((torch.rand(n, generator=g) < 0.5)[:, None], uniform, lobe)
        q = 0.5 / (2 * math.pi) * (wo[:, 2] > 0) + 0.5 * ref.pdf(wi, wo)
        f = model.eval(wi, wo)
        neural = float(torch.where(q[:, None] > 0, f / q.clamp_min(1e-12)[:, None], 0.0).mean())
    return neural, float(w.mean())


@pytest.mark.slow
def test_fast_keeps_the_grazing_energy_of_a_sharp_coat(carpaint, tmp_path):
    """The fast preset on the CarPaint: at 10 degrees above the horizon the coat carries most of the reference's
    albedo (0.66, grey average), and the model keeps it: the test asks at least 85 % of the reference. It
    overshoots a little instead (measured 0.73, 111 %, at seed 0 with 2000 steps of 1024 rows; 129-136 % with 1000
    of 2048), so the upper bound is 150 %: it catches a runaway, not the known overshoot (``grazing_fraction``
    removes it for this material). The mollification floor (1 degree, MIS) was what kept this energy with 1000
    steps of 2048 rows and the balance's gain of 0.3: without it the decoder lost half (0.31 when the floor was
    added, 0.54 on 2026-12-07 against 0.81 with it). With 2000 steps of 1024 rows and a gain of 0.5 the model
    without the floor keeps 0.63 (96 %) as well, so the comparison run is gone; ``fast`` keeps the floor, not
    measured without it on the other samples since (docs/history/fast-schedule-2026-12-07.md). (Shorter runs are not
    settled: at 300 steps, with a quarter of lobe directions, it overshot by a third.)"""
    stack = build_parameter_stack(carpaint.compiled)
    with_floor = Trainer(carpaint, stack, preset("fast"), tmp_path / "on").run(progress=False)
    a_on, a_ref = _grazing_albedo(with_floor, carpaint, 10.0)
    assert 0.85 < a_on / a_ref < 1.5, (a_on, a_ref)
