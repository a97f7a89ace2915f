"""Sampling of the reference: chi-square goodness of fit, pdf normalisation, weight = eval/pdf.

Near-delta lobes (roughness 0, e.g. the glass, chrome and thin-film examples)
are left out: a chi-square histogram cannot resolve them.

Every ``sample()`` (each closure on its own, and whole example materials) is
tested with Pearson's chi-square test against its own ``pdf()`` at a fixed
``wi``. The significance 0.01 is Šidák-corrected for the number of chi-square
tests in this file, so the family of tests has a 1% false-failure rate.
"""

from __future__ import annotations

import math

import MaterialX as mx
import pytest
import torch
from closure_docs import closure_material
from conftest import random_dirs, shared_path
from sampler_checks import sampler_chi2

from mtlx2neural.graph import compile_material
from mtlx2neural.reference import ReferenceMaterial
from mtlx2neural.verify.chi2 import pdf_integral

CLOSURES = {
    "oren_nayar": ("oren_nayar_diffuse_bsdf", dict(color=(0.8, 0.5, 0.2), roughness=0.5)),
    "oren_nayar_ec": ("oren_nayar_diffuse_bsdf", dict(roughness=1.0, energy_compensation=True)),
    "burley": ("burley_diffuse_bsdf", dict(roughness=0.7)),
    "dielectric": ("dielectric_bsdf", dict(roughness=(0.3, 0.3), ior=1.5)),
    "dielectric_aniso": ("dielectric_bsdf", dict(roughness=(0.5, 0.08), ior=1.8)),
    "dielectric_retro": ("dielectric_bsdf", dict(roughness=(0.4, 0.4), retroreflective=True)),
    "conductor": ("conductor_bsdf", dict(roughness=(0.2, 0.2))),
    "generalized_schlick": ("generalized_schlick_bsdf", dict(roughness=(0.35, 0.2), color0=(0.9, 0.6, 0.3))),
    "sheen": ("sheen_bsdf", dict(roughness=0.3)),
    "sheen_zeltner": ("sheen_bsdf", dict(roughness=0.5, mode="zeltner")),
    "thin_film": ("dielectric_bsdf", dict(roughness=(0.25, 0.25), thinfilm_thickness=450.0, thinfilm_ior=1.4)),
}
EXAMPLES = [
    ("StandardSurface", "standard_surface_default.mtlx"),
    ("StandardSurface", "standard_surface_velvet.mtlx"),
    ("StandardSurface", "standard_surface_copper.mtlx"),
    ("StandardSurface", "standard_surface_jade.mtlx"),
    ("StandardSurface", "standard_surface_metal_brushed.mtlx"),
    ("UsdPreviewSurface", "usd_preview_surface_plastic.mtlx"),
]
WI_ANGLES = (20.0, 70.0)
N_CHI2 = (len(CLOSURES) + len(EXAMPLES)) * len(WI_ANGLES)


def _wi(deg: float) -> torch.Tensor:
    t = math.radians(deg)
    return torch.tensor([[math.sin(t) * 0.8, math.sin(t) * 0.6, math.cos(t)]])


def _example(folder, name) -> ReferenceMaterial:
    path = shared_path("materialx", "resources", "Materials", "Examples", folder, name)
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(path))
    return ReferenceMaterial(compile_material(doc, None))


def _chi2(m: ReferenceMaterial, deg: float):
    return sampler_chi2(m, _wi(deg), N_CHI2)


@pytest.mark.parametrize("deg", WI_ANGLES)
@pytest.mark.parametrize("name", list(CLOSURES))
def test_closure_sampler_chi2(name, deg):
    cat, kw = CLOSURES[name]
    result = _chi2(closure_material(cat, **kw), deg)
    assert result.passed, result.message


@pytest.mark.parametrize("deg", WI_ANGLES)
@pytest.mark.parametrize("folder,name", EXAMPLES)
def test_example_material_sampler_chi2(folder, name, deg):
    result = _chi2(_example(folder, name), deg)
    assert result.passed, result.message


@pytest.mark.parametrize("name", list(CLOSURES))
def test_pdf_integrates_to_the_probability_of_a_sample_above_the_horizon(name):
    # pdf is 0 at or below the horizon (the material contract), where sample() gives weight 0 and
    # pdf 0: over the sphere it integrates to 1 minus the probability of such a failed sample.
    cat, kw = CLOSURES[name]
    m = closure_material(cat, **kw)
    wi = _wi(45.0)
    total = pdf_integral(lambda wo: m.pdf(wi.expand(wo.shape[0], 3), wo.float()).double(), resolution=512)
    n = 1 << 17
    wo, _, _ = m.sample(wi.expand(n, 3), torch.rand(n, 2, generator=torch.Generator().manual_seed(6)))
    above = float((wo[:, 2] > 0).double().mean())
    # 1% is the acceptance bound; the quadrature itself is accurate to ~1e-4 for these lobes, and the
    # Monte Carlo fraction (p <= ~0.07 of 2^17 samples below the horizon) to ~7e-4 (one sigma).
    assert above > 0.5 and abs(total - above) < 0.01, (total, above)


@pytest.mark.parametrize("name", list(CLOSURES))
def test_weight_is_eval_over_pdf(name):
    cat, kw = CLOSURES[name]
    m = closure_material(cat, **kw)
    wi = random_dirs(4096, seed=3)
    u = torch.rand(4096, 2, generator=torch.Generator().manual_seed(4))
    wo, weight, pdf = m.sample(wi, u)
    ok = pdf > 1e-6
    expected = m.eval(wi, wo)[ok] / pdf[ok, None]
    # Same float32 maths on both sides, but evaluated in separate calls: allow a few ulps.
    torch.testing.assert_close(weight[ok], expected, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(pdf, m.pdf(wi, wo), rtol=1e-5, atol=1e-6)
