"""The analytic baseline's Slang twin (codegen/slang/AnalyticMaterial.slang) against its torch model.

Run on slangpy's CPU device through :class:`mtlx2neural.baseline.shader_harness.CpuAnalytic`.
Tolerance (eval, against the torch formula in float64 on the shader's float32 inputs; relative,
floor 1e-3 in the denominator): 99.9% within 1e-4, and the maximum within 4x the torch float32
model's own maximum deviation from float64. The GGX term 1 + (n.h)^2 (alpha^2 - 1) cancels near
the peak of sharp lobes (roughness down to 0.02), which amplifies float32 rounding (6e-8) by
~1e3-1e4 there, in both float32 implementations alike. Texel-centre fetches: max 1e-4.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mtlx2neural.baseline.analytic_model import AnalyticMaterial, brdf, decode
from mtlx2neural.codegen.cpu import slangpy_available
from mtlx2neural.contract import ShadingPoint

OK, REASON = slangpy_available()
pytestmark = pytest.mark.skipif(not OK, reason=f"slangpy CPU device unavailable: {REASON}")

N = 32768


@pytest.fixture(scope="module")
def shader():
    from mtlx2neural.baseline.shader_harness import CpuAnalytic

    return CpuAnalytic()


def directions(n, g, up=0.9):
    w = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    keep = torch.rand(n, generator=g) < up
    w[:, 2] = torch.where(keep, w[:, 2].abs(), w[:, 2])
    return w


def random_raw(n, g):
    """Unconstrained channels spanning the whole parameter space (sigmoid saturates at +-6)."""
    raw = torch.randn(n, 8, generator=g) * 3
    raw[:, 6:8] *= 0.3  # normal slopes: tilts up to ~70 degrees
    return raw


def params64(ch: torch.Tensor) -> dict:
    """decode()'s dict from decoded channels [N, 8], in float64."""
    ch = ch.double()
    n = torch.cat([-ch[:, 6:8], torch.ones_like(ch[:, :1])], -1)
    return {"base": ch[:, 0:3], "roughness": ch[:, 3:4], "metalness": ch[:, 4:5], "specular": ch[:, 5:6],
            "normal": n / n.norm(dim=-1, keepdim=True)}


def rel(a, b, floor=1e-3):
    return np.abs(a - b) / np.maximum(np.abs(b), floor)


def test_eval_matches_torch(shader):
    from mtlx2neural.baseline.shader_harness import decoded_channels

    g = torch.Generator().manual_seed(0)
    raw, wi, wo = random_raw(N, g), directions(N, g), directions(N, g)
    ch = decoded_channels(decode(raw))
    ref = brdf(params64(ch), wi.double(), wo.double()).numpy()  # the shader's inputs, in float64
    got = shader.eval(ch.numpy(), wi.numpy(), wo.numpy())
    assert (ref > 0).any(axis=1).mean() > 0.5  # most queries above the horizon: a real comparison
    err = rel(got, ref)
    own = rel(brdf({k: v.float() for k, v in params64(ch).items()}, wi, wo).numpy(), ref)
    print(f"analytic eval: max rel {err.max():.3g}, p99.9 {np.quantile(err, 0.999):.3g}; "
          f"torch float32 max {own.max():.3g}")
    assert np.quantile(err, 0.999) <= 1e-4
    assert err.max() <= max(4 * own.max(), 1e-4)
    below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
    assert np.all(got[below.numpy()] == 0)


def test_extremes_stay_finite(shader):
    """Grazing and horizon directions, roughness at its floor, extreme slopes: finite, non-negative."""
    g = torch.Generator().manual_seed(1)
    n = 4096
    ch = torch.zeros(n, 8)
    ch[:, 0:3] = torch.rand(n, 3, generator=g)
    ch[:, 3] = 0.02
    ch[:, 4:6] = torch.rand(n, 2, generator=g)
    ch[:, 6:8] = torch.randn(n, 2, generator=g) * 1e4
    wi = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    wi[:, 2] = torch.rand(n, generator=g) * 1e-6
    wo = wi * torch.tensor([-1.0, -1.0, 1.0])  # mirror: the GGX peak, where D is largest
    got = shader.eval(ch.numpy(), wi.numpy(), wo.numpy())
    assert np.isfinite(got).all() and (got >= 0).all()


def test_fetch_eval_matches_the_model_at_texel_centres(shader):
    """Fetch (stochastic level, bilinear periodic) + eval against AnalyticMaterial.eval at texel
    centres of level 0, where filtering decoded channels equals decoding filtered ones."""
    from mtlx2neural.baseline.shader_harness import decoded_levels

    torch.manual_seed(2)
    model = AnalyticMaterial((4, 6))
    with torch.no_grad():
        for lv in model.maps.levels:
            lv.normal_(0, 1.5)
    g = torch.Generator().manual_seed(3)
    n = 2048
    ix, iy = torch.randint(0, 6, (n,), generator=g), torch.randint(0, 4, (n,), generator=g)
    uv = torch.stack([(ix + 0.5) / 6, 1 - (iy + 0.5) / 4], -1)
    lod, u = torch.zeros(n), torch.rand(n, generator=g)
    wi, wo = directions(n, g, up=1.0), directions(n, g, up=1.0)
    with torch.no_grad():
        ref = model.eval(wi, wo, ShadingPoint(uv=uv, lod=lod, u_level=u)).numpy()
    got = shader.fetch_eval(shader.pyramid(decoded_levels(model)), uv.numpy(), lod.numpy(), u.numpy(),
                            wi.numpy(), wo.numpy())
    err = rel(got, ref)
    assert err.max() <= 1e-4, err.max()
    # and the texel matters: reading every query at texel (0, 0) instead fails the comparison
    uv0 = torch.tensor([[0.5 / 6, 1 - 0.5 / 4]]).expand(n, 2)
    wrong = shader.fetch_eval(shader.pyramid(decoded_levels(model)), uv0.numpy(), lod.numpy(), u.numpy(),
                              wi.numpy(), wo.numpy())
    assert rel(wrong, ref).max() > 1e-2
