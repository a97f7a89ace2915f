"""A shading model's canonical form (mtlx2neural.universal.canonical): the same BRDF, one program for every
material of the model, and a clear reason for a material it does not cover."""

from __future__ import annotations

import MaterialX as mx
import pytest
import torch
from conftest import random_dirs, shared_path
from materials import document

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
    disney = _read(shared_path("materialx", "resources", "Materials", "TestSuite", "pbrlib", "surfaceshader",
                               "transparency_hints.mtlx"))
    disney.getNode("geometric_opacity_hint").setCategory("disney_principled")
    elig = eligibility(disney, "geom_hint")
    assert elig.model is None and "disney_principled" in elig.reason and "standard_surface" in elig.reason
    with pytest.raises(ValueError, match="disney_principled"):
        canonical_document(disney, "geom_hint")
    for name, held in (("glass", "transmission"), ("velvet", "sheen"), ("metal_brushed", "specular_anisotropy")):
        assert held in eligibility(_ss_example(name)).reason, name  # another program than the four lobes
    assert "transparent" in eligibility(_example("glass")).reason  # transmission: another program
    doc = _example("plastic")
    doc.getNodes("UsdPreviewSurface")[0].setInputValue("useSpecularWorkflow", 1)
    assert "useSpecularWorkflow" in eligibility(doc).reason


NOISE = ('  <noise2d name="noise" type="float">\n    <input name="amplitude" type="float" value="0.5" />\n'
         '    <input name="pivot" type="float" value="0.5" />\n  </noise2d>\n')
"""A spatial float in [0, 1] to connect an input to (``@noise``)."""


def _shader(category: str, **inputs) -> mx.Document:
    """One ``category`` material ``M`` with ``inputs`` as (type, value string) pairs; a value ``@noise``
    connects the input to :data:`NOISE`."""
    def line(k, t, v):
        source = 'nodename="noise"' if v == "@noise" else f'value="{v}"'
        return f'    <input name="{k}" type="{t}" {source} />\n'

    text = document(NOISE, f'  <{category} name="SR" type="surfaceshader">\n',
                    *(line(k, t, v) for k, (t, v) in inputs.items()),
                    f'  </{category}>\n  <surfacematerial name="M" type="material">\n'
                    '    <input name="surfaceshader" type="surfaceshader" nodename="SR" />\n  </surfacematerial>\n')
    doc = mx.createDocument()
    mx.readFromXmlString(doc, text)
    return doc


MODEL_CASES = {
    "open_pbr_surface": [{}, {"base_metalness": ("float", "1"), "specular_roughness": ("float", "0.2")},
                         {"coat_weight": ("float", "1"), "coat_roughness": ("float", "0.05"),
                          "base_color": ("color3", "0.6, 0.1, 0.1")}],
    # glTF's defaults are a rough metal; a cut-out's alpha lives beside the BRDF in either alpha mode
    "gltf_pbr": [{}, {"metallic": ("float", "1"), "roughness": ("float", "0.2")},
                 {"metallic": ("float", "0"), "clearcoat": ("float", "1"), "clearcoat_roughness": ("float", "0.05"),
                  "base_color": ("color3", "0.6, 0.1, 0.1")},
                 {"metallic": ("float", "0"), "alpha": ("float", "@noise"), "alpha_mode": ("integer", "1")},
                 {"metallic": ("float", "0"), "sheen_color": ("color3", "0, 0, 0"), "alpha_mode": ("integer", "2"),
                  "alpha": ("float", "@noise")}],
}
"""Per model: materials its universal network covers (a default, a metal, a coated dielectric, ...)."""
REFUSED = {"open_pbr_surface": [({"fuzz_weight": ("float", "0.5")}, "fuzz_weight")],
           "gltf_pbr": [({"sheen_color": ("color3", "0.5, 0.5, 0.5")}, "sheen_color"),
                        ({"transmission": ("float", "@noise")}, "transmission"),
                        ({"anisotropy_strength": ("float", "0.5")}, "anisotropy_strength")]}


@pytest.mark.parametrize("model", sorted(MODEL_CASES))
def test_materials_of_a_model_keep_their_brdf_in_the_atlas_layout(tmp_path, model):
    """Each of :data:`MODEL_CASES`: the canonical form keeps its BRDF (float32 rounding) and compiles to the
    atlas's layout; each of :data:`REFUSED` is refused with the input that takes it off the model."""
    from mtlx2neural.textures.parameter_stack import build_parameter_stack
    from mtlx2neural.universal.canonical import canonical_name
    from mtlx2neural.universal.train import atlas_material

    _, _, atlas = atlas_material(tmp_path, model, 16, 0)
    layout = [(canonical_name(c.name), c.width) for c in atlas.channels]
    wi, wo = random_dirs(512, 1), random_dirs(512, 2)
    uv = torch.rand(512, 2, generator=torch.Generator().manual_seed(3))
    for inputs in MODEL_CASES[model]:
        doc = _shader(model, **inputs)
        assert eligibility(doc, "M").model == model, inputs
        canonical = compile_material(canonical_document(doc, "M"), "M")
        assert [(canonical_name(c.name), c.width) for c in build_parameter_stack(canonical).channels] == layout
        a = ReferenceMaterial(compile_material(doc, "M")).eval(wi, wo, ShadingPoint(uv=uv))
        b = ReferenceMaterial(canonical).eval(wi, wo, ShadingPoint(uv=uv))
        assert torch.allclose(a, b, rtol=1e-5, atol=1e-7) and float(a.max()) > 0.02, inputs
    for inputs, held in REFUSED[model]:
        elig = eligibility(_shader(model, **inputs), "M")
        assert elig.model is None and held in elig.reason, inputs


@pytest.mark.parametrize("model", ["open_pbr_surface", "gltf_pbr"])
def test_the_benchmark_s_model_copy_of_the_chess_set_is_of_the_model(tmp_path, model):
    """``benchmarks/model_copy.py`` (the universal benchmark's textured OpenPBR and glTF materials): the chess
    set's nine covered Standard Surfaces become valid shaders of ``model`` that its network covers, reading the same
    textures; glTF's unauthored inputs are written at Standard Surface's defaults, not glTF's rough metal."""
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[2] / "benchmarks" / "model_copy.py"
    if not script.is_file():
        pytest.skip("not a source checkout: no benchmarks/model_copy.py")
    src = shared_path("materialx", "resources", "Materials", "Examples", "StandardSurface",
                      "standard_surface_chess_set.mtlx")
    subprocess.run([sys.executable, str(script), str(src), str(tmp_path), "--model", model], check=True,
                   capture_output=True)
    doc = _read(tmp_path / f"standard_surface_chess_set_{model}.mtlx")
    assert doc.validate()[0]
    covered = [m.getName() for m in doc.getMaterialNodes() if eligibility(doc, m.getName()).model == model]
    assert len(covered) == 9 and "M_Chessboard" in covered
    shader = doc.getNode(doc.getNode("M_Chessboard").getInput("surfaceshader").getNodeName())
    assert shader.getCategory() == model
    assert shader.getInput("base_color").getNodeGraphString() == "NG_ChessBoard"  # the same texture graph
    if model == "gltf_pbr":
        assert shader.getInputValue("specular") == 1.0 and shader.getInputValue("ior") == 1.5
