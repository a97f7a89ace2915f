"""The public API on the bundled sample stage (needs no ../shared)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from conftest import random_dirs

import mtlx2neural as m2n
from mtlx2neural.errors import InputError

SAMPLE = Path(__file__).resolve().parents[1] / "samples" / "layered_spheres.usda"


@pytest.fixture(scope="module")
def carpaint():
    return m2n.load_reference(SAMPLE, material="/World/Looks/CarPaint")


def test_shapes_and_conventions(carpaint):
    wi, wo = random_dirs(1000, seed=1), random_dirs(1000, seed=2)
    f = carpaint.eval(wi, wo)
    assert f.shape == (1000, 3) and f.dtype == torch.float32 and bool((f >= 0).all())
    # Below the horizon the cosine-weighted BRDF is exactly zero.
    assert bool((carpaint.eval(wi, -wo) == 0).all())
    assert carpaint.pdf(wi, wo).shape == (1000,)
    assert carpaint.albedo(wi[:4], samples=64).shape == (4, 3)


def test_sample_with_three_random_numbers(carpaint):
    wi = random_dirs(2048, seed=3)
    u = torch.rand(2048, 3, generator=torch.Generator().manual_seed(5))
    wo, weight, pdf = carpaint.sample(wi, u)
    ok = pdf > 1e-6
    # weight and eval/pdf are the same float32 maths evaluated in separate calls.
    torch.testing.assert_close(weight[ok], carpaint.eval(wi, wo)[ok] / pdf[ok, None], rtol=1e-5, atol=1e-6)
    assert bool(torch.isfinite(wo).all())


def test_describe_reports_layering(carpaint):
    info = carpaint.describe()
    kept = [k["closure"] for k in info["lobes_kept"]]
    assert kept == ["dielectric_bsdf", "conductor_bsdf", "dielectric_bsdf", "oren_nayar_diffuse_bsdf"]
    assert info["material"] == "/World/Looks/CarPaint"
    assert not info["textures"]


def test_sample_materials_conserve_energy_at_normal_incidence():
    # 4096 Sobol samples estimate these smooth albedos to ~1e-3; both are well below 1.
    paint = m2n.load_reference(SAMPLE, material="/World/Looks/CarPaint")
    plastic = m2n.load_reference(SAMPLE, material="Plastic")  # by prim name
    wi = torch.tensor([[0.0, 0.0, 1.0]])
    a_paint, a_plastic = paint.albedo(wi, samples=4096), plastic.albedo(wi, samples=4096)
    assert bool((a_paint <= 1.0 + 1e-3).all()) and bool((a_plastic <= 1.0 + 1e-3).all())


def test_unknown_or_skipped_material_errors():
    with pytest.raises(InputError, match="Nope"):
        m2n.load_reference(SAMPLE, material="Nope")
    # A skipped material can still be loaded when named explicitly.
    hidden = m2n.load_reference(SAMPLE, material="/World/Looks/Hidden")
    assert hidden.describe()["lobes_kept"]
