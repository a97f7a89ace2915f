"""A shading model's canonical form (mtlx2neural.universal.canonical): the same BRDF, one program for every
material of the model, and a clear reason for a material it does not cover."""

from __future__ import annotations

import MaterialX as mx
import pytest
import torch
from conftest import random_dirs, shared_path

from mtlx2neural.contract import ShadingPoint
from mtlx2neural.graph.compile import compile_material
from mtlx2neural.reference.material import ReferenceMaterial
from mtlx2neural.universal.canonical import (
    canonical_document,
    canonical_names,
    eligibility,
)

EXAMPLES = ("default", "gold", "carpaint", "plastic")
SS_EXAMPLES = ("default", "gold", "plastic", "brass_tiled", "onyx_hextiled")
"""MaterialX's Standard Surface examples the standard_surface model covers: a plain one, a metal, a plastic,
textured ones (the brass's colour texture is missing from the assets: allow_missing_textures)."""


def _read(path) -> mx.Document:
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(path))
    return doc


def _example(name):
    return _read(shared_path("materialx", "resources", "Materials", "Examples", "UsdPreviewSurface",
                             f"usd_preview_surface_{name}.mtlx"))


def _ss_example(name):
    return _read(shared_path("materialx", "resources", "Materials", "Examples", "StandardSurface",
                             f"standard_surface_{name}.mtlx"))


@pytest.mark.parametrize("model,name", [("UsdPreviewSurface", n) for n in EXAMPLES]
                         + [("standard_surface", n) for n in SS_EXAMPLES])
def test_the_canonical_form_keeps_the_brdf(model, name):
    doc = _example(name) if model == "UsdPreviewSurface" else _ss_example(name)
    material = doc.getMaterialNodes()[0].getName()
    assert eligibility(doc, material).model == model
    original = ReferenceMaterial(compile_material(doc, material, allow_missing_textures=True))
    canonical = ReferenceMaterial(compile_material(canonical_document(doc, material), material,
                                                   allow_missing_textures=True))
    wi, wo = random_dirs(512, 1), random_dirs(512, 2)
    uv = torch.rand(512, 2, generator=torch.Generator().manual_seed(3))
    a, b = original.eval(wi, wo, ShadingPoint(uv=uv)), canonical.eval(wi, wo, ShadingPoint(uv=uv))
    # the rewrite adds 0 to each input: the same arithmetic up to float32 rounding of the unfolded program
    assert torch.allclose(a, b, rtol=1e-5, atol=1e-7)


def test_every_material_of_the_model_compiles_to_one_layout():
    layouts = set()
    for name in EXAMPLES:
        doc = _example(name)
        material = doc.getMaterialNodes()[0].getName()
        plain = compile_material(doc, material)
        compiled = compile_material(canonical_document(doc, material), material)
        layouts.add(tuple(canonical_names(k for k, _, _ in compiled.varying_parameters())))
        # the originals differ: metal-only gold and coated car paint fold to other leaves
        assert len(plain.program.leaves()) <= len(compiled.program.leaves())
    assert len(layouts) == 1
    assert {"coat_dielectric_bsdf.roughness", "metalness_workflow_bsdf.mix", "diffuse_bsdf.color"} <= set(*layouts)


def test_standard_surface_materials_compile_to_one_layout():
    """Plain, metal and textured Standard Surfaces (a normal map on the brass and the onyx, none on the others:
    the canonical form's flat normal map stands in) share one program and layout with all four lobes."""
    layouts = set()
    for name in SS_EXAMPLES:
        doc = _ss_example(name)
        material = doc.getMaterialNodes()[0].getName()
        compiled = compile_material(canonical_document(doc, material), material, allow_missing_textures=True)
        layouts.add(tuple(canonical_names(k for k, _, _ in compiled.varying_parameters())))
    assert len(layouts) == 1
    assert {"coat_bsdf.roughness", "metal_bsdf.roughness", "specular_bsdf.normal", "diffuse_bsdf.color"} <= set(*layouts)


def test_a_material_it_does_not_cover_is_named_with_the_reason():
    hints = _read(shared_path("materialx", "resources", "Materials", "TestSuite", "pbrlib", "surfaceshader",
                              "transparency_hints.mtlx"))
    assert "transmission_weight" in eligibility(hints, "transp_hint").reason  # an OpenPBR glass
    gltf = _read(shared_path("materialx", "resources", "Materials", "TestSuite", "pbrlib", "surfaceshader",
                             "transparency_hints.mtlx"))
    gltf.getNode("geometric_opacity_hint").setCategory("gltf_pbr")
    elig = eligibility(gltf, "geom_hint")
    assert elig.model is None and "gltf_pbr" in elig.reason and "standard_surface" in elig.reason
    with pytest.raises(ValueError, match="gltf_pbr"):
        canonical_document(gltf, "geom_hint")
    for name, held in (("glass", "transmission"), ("velvet", "sheen"), ("metal_brushed", "specular_anisotropy")):
        assert held in eligibility(_ss_example(name)).reason, name  # another program than the four lobes
    assert "transparent" in eligibility(_example("glass")).reason  # transmission: another program
    doc = _example("plastic")
    doc.getNodes("UsdPreviewSurface")[0].setInputValue("useSpecularWorkflow", 1)
    assert "useSpecularWorkflow" in eligibility(doc).reason


def _open_pbr(**inputs) -> mx.Document:
    """One open_pbr_surface material ``M`` with ``inputs`` as (type, value string) pairs."""
    text = ('<?xml version="1.0"?>\n<materialx version="1.39">\n  <open_pbr_surface name="SR" type="surfaceshader">\n'
            + "".join(f'    <input name="{k}" type="{t}" value="{v}" />\n' for k, (t, v) in inputs.items())
            + '  </open_pbr_surface>\n  <surfacematerial name="M" type="material">\n'
            '    <input name="surfaceshader" type="surfaceshader" nodename="SR" />\n  </surfacematerial>\n</materialx>\n')
    doc = mx.createDocument()
    mx.readFromXmlString(doc, text)
    return doc


def test_open_pbr_materials_keep_their_brdf_in_one_layout(tmp_path):
    """A default, a metal and a coated OpenPBR Surface: the canonical form keeps each BRDF (float32 rounding) and
    compiles all three to the atlas's layout; a fuzzy one is refused with the reason."""
    from mtlx2neural.textures.parameter_stack import build_parameter_stack
    from mtlx2neural.universal.canonical import canonical_name
    from mtlx2neural.universal.train import atlas_material

    cases = [_open_pbr(), _open_pbr(base_metalness=("float", "1"), specular_roughness=("float", "0.2")),
             _open_pbr(coat_weight=("float", "1"), coat_roughness=("float", "0.05"), base_color=("color3", "0.6, 0.1, 0.1"))]
    _, _, atlas = atlas_material(tmp_path, "open_pbr_surface", 16, 0)
    layout = [(canonical_name(c.name), c.width) for c in atlas.channels]
    wi, wo = random_dirs(512, 1), random_dirs(512, 2)
    uv = torch.rand(512, 2, generator=torch.Generator().manual_seed(3))
    for doc in cases:
        assert eligibility(doc, "M").model == "open_pbr_surface"
        canonical = compile_material(canonical_document(doc, "M"), "M")
        assert [(canonical_name(c.name), c.width) for c in build_parameter_stack(canonical).channels] == layout
        a = ReferenceMaterial(compile_material(doc, "M")).eval(wi, wo, ShadingPoint(uv=uv))
        b = ReferenceMaterial(canonical).eval(wi, wo, ShadingPoint(uv=uv))
        assert torch.allclose(a, b, rtol=1e-5, atol=1e-7) and float(a.max()) > 0.02
    assert "fuzz_weight" in eligibility(_open_pbr(fuzz_weight=("float", "0.5")), "M").reason
