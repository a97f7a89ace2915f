"""Numerical extremes of the reference, as property tests (hypothesis).

Directions at and around the horizon (z = 0, +-1e-8), exactly normal; roughness
0 and 1; IOR 1 and 50; black and >1 colours; anisotropy +-1; shading normals
that point below the horizon. No NaN or Inf may ever come out, and energy-
conserving closures must pass a white furnace test.
"""

from __future__ import annotations

import functools
import math

import MaterialX as mx
import pytest
import torch
from closure_docs import closure_material
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mtlx2neural.graph import compile_material
from mtlx2neural.reference import ReferenceMaterial

SPECIAL_Z = [0.0, 1e-8, -1e-8, 1.0, -1.0, 1e-4, 0.5]
ROUGH = [0.0, 1.0, 1e-4, 0.5]
IOR = [1.0, 50.0, 1.5]
COLOR = [(0.0, 0.0, 0.0), (2.5, 1.5, 3.0), (0.8, 0.2, 0.1)]
BELOW = (0.6, 0.0, -0.8)  # a shading normal pointing below the geometric horizon


def _direction(z: float, phi: float) -> torch.Tensor:
    s = math.sqrt(max(0.0, 1.0 - z * z))
    return torch.tensor([s * math.cos(phi), s * math.sin(phi), z])


directions = st.builds(_direction, st.sampled_from(SPECIAL_Z) | st.floats(-1, 1), st.floats(0, 2 * math.pi))


@functools.lru_cache(maxsize=None)
def _closure(kind: str, rough: float, ior: float, color: tuple, normal: tuple) -> ReferenceMaterial:
    common = {"normal": normal}
    if kind == "dielectric":
        return closure_material("dielectric_bsdf", roughness=(rough, rough), ior=ior, tint=color, **common)
    if kind == "conductor":
        return closure_material("conductor_bsdf", roughness=(rough, rough * 0.5), ior=color, extinction=(ior,) * 3,
                                **common)
    if kind == "schlick":
        return closure_material("generalized_schlick_bsdf", roughness=(rough, rough), color0=color, **common)
    if kind == "thin_film":
        return closure_material("dielectric_bsdf", roughness=(rough, rough), ior=ior, thinfilm_thickness=700.0,
                                thinfilm_ior=1.33, **common)
    if kind == "oren_nayar":
        return closure_material("oren_nayar_diffuse_bsdf", roughness=rough, color=color, **common)
    if kind == "oren_nayar_ec":
        return closure_material("oren_nayar_diffuse_bsdf", roughness=rough, color=color, energy_compensation=True,
                                **common)
    if kind == "burley":
        return closure_material("burley_diffuse_bsdf", roughness=rough, color=color, **common)
    if kind == "sheen":
        return closure_material("sheen_bsdf", roughness=rough, color=color, **common)
    if kind == "sheen_zeltner":
        return closure_material("sheen_bsdf", roughness=rough, color=color, mode="zeltner", **common)
    if kind == "subsurface":
        return closure_material("subsurface_bsdf", color=color, radius=(1.0, 0.5, 0.1), **common)
    if kind == "translucent":
        return closure_material("translucent_bsdf", color=color, **common)
    raise KeyError(kind)


@functools.lru_cache(maxsize=None)
def _standard_surface(rough: float, ior: float, aniso: float, below: bool) -> ReferenceMaterial:
    doc = mx.createDocument()
    sh = doc.addNode("standard_surface", "sh", "surfaceshader")
    for name, value in (("specular_roughness", rough), ("specular_IOR", ior), ("specular_anisotropy", aniso),
                        ("coat", 0.7), ("coat_roughness", rough), ("sheen", 0.5), ("metalness", 0.3),
                        ("subsurface", 0.2), ("thin_film_thickness", 300.0)):
        sh.setInputValue(name, value, "float")
    if below:  # a normal map whose texel points below the horizon
        nm = doc.addNode("normalmap", "nm", "vector3")
        nm.setInputValue("in", mx.Vector3(0.5, 0.5, 0.0), "vector3")
        sh.setConnectedNode("normal", nm)
        sh.setConnectedNode("coat_normal", nm)
    doc.addMaterialNode("M", sh)
    return ReferenceMaterial(compile_material(doc, "M"))


KINDS = ["dielectric", "conductor", "schlick", "thin_film", "oren_nayar", "oren_nayar_ec", "burley", "sheen",
         "sheen_zeltner", "subsurface", "translucent"]
materials = st.one_of(
    st.builds(_closure, st.sampled_from(KINDS), st.sampled_from(ROUGH), st.sampled_from(IOR), st.sampled_from(COLOR),
              st.sampled_from([(0.0, 0.0, 1.0), BELOW])),
    st.builds(_standard_surface, st.sampled_from(ROUGH), st.sampled_from(IOR), st.sampled_from([-1.0, 0.0, 1.0]),
              st.booleans()),
)


def _all_finite(*ts):
    return all(bool(torch.isfinite(t).all()) for t in ts)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True)
@given(m=materials, wi=directions, wo=directions, u=st.tuples(st.floats(0, 1, exclude_max=True),
                                                              st.floats(0, 1, exclude_max=True)))
def test_no_nan_or_inf_anywhere(m, wi, wo, u):
    wi, wo = wi[None], wo[None]
    f = m.eval(wi, wo)
    assert _all_finite(f) and bool((f >= 0).all())
    if wi[0, 2] <= 0 or wo[0, 2] <= 0:
        assert bool((f == 0).all()), "eval must be 0 at or below the horizon"
    s_wo, weight, pdf = m.sample(wi, torch.tensor([u]))
    assert _all_finite(s_wo, weight, pdf, m.pdf(wi, wo))
    assert bool((weight >= 0).all()) and bool((pdf >= 0).all())


@pytest.mark.parametrize("kind", KINDS)
def test_albedo_finite_at_extremes(kind):
    z = torch.tensor(SPECIAL_Z)
    wi = torch.stack([torch.sqrt((1 - z * z).clamp_min(0)), torch.zeros_like(z), z], -1)
    for rough in ROUGH:
        for normal in [(0.0, 0.0, 1.0), BELOW]:
            a = _closure(kind, rough, 50.0, (2.5, 1.5, 3.0), normal).albedo(wi, samples=64)
            assert _all_finite(a)
            assert bool((a[z <= 0] == 0).all())


# White furnace: these closures conserve energy in MaterialX's own definitions.
# Measured exceptions, kept out of the furnace on purpose (MaterialX behaviour the
# oracle test confirms): Burley diffuse (up to 1.56 at grazing, by design), the
# energy-compensated Oren-Nayar (up to 1.16: MaterialX clamps LdotV at 1e-8 before
# using its sign), and GGX conductors / generalized Schlick (up to ~1.05 at grazing:
# the analytic albedo fit and isotropic G2 with anisotropic D).
FURNACE = {
    "oren_nayar_rough0": ("oren_nayar_diffuse_bsdf", dict(color=(1, 1, 1), roughness=0.0)),
    "oren_nayar_rough1": ("oren_nayar_diffuse_bsdf", dict(color=(1, 1, 1), roughness=1.0)),
    "dielectric_rough": ("dielectric_bsdf", dict(roughness=(1.0, 1.0), ior=50.0)),
    "dielectric_mid": ("dielectric_bsdf", dict(roughness=(0.3, 0.3), ior=1.5)),
    "dielectric_ior1": ("dielectric_bsdf", dict(roughness=(0.3, 0.3), ior=1.0)),
    "sheen": ("sheen_bsdf", dict(roughness=0.3)),
    "sheen_rough1": ("sheen_bsdf", dict(roughness=1.0)),
    "sheen_zeltner": ("sheen_bsdf", dict(roughness=0.5, mode="zeltner")),
}


@pytest.mark.parametrize("name", list(FURNACE))
def test_white_furnace(name):
    cat, kw = FURNACE[name]
    m = closure_material(cat, **kw)
    cos = torch.tensor([1.0, 0.8, 0.5, 0.2, 0.05, 1e-3])
    wi = torch.stack([torch.sqrt(1 - cos ** 2), torch.zeros_like(cos), cos], -1)
    a = m.albedo(wi, samples=1 << 14)
    # 1e-3 is the acceptance bound; 2^14 scrambled Sobol samples of these smooth
    # integrands estimate albedo to ~1e-4 (checked against quadrature).
    assert float(a.max()) <= 1.0 + 1e-3, a
