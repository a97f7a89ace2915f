"""Graph compiler: generic nodegraph expansion, constant folding, lobe pruning, spatial split."""

from __future__ import annotations

import MaterialX as mx
import pytest
import torch
from conftest import shared_path

from mtlx2neural.errors import InputError, UnsupportedNodeError
from mtlx2neural.graph import compile_material

SHADING_MODELS = ["standard_surface", "open_pbr_surface", "gltf_pbr", "UsdPreviewSurface", "disney_principled"]


def _doc_with(category: str, **inputs):
    doc = mx.createDocument()
    sh = doc.addNode(category, "shader", "surfaceshader")
    for name, (mx_type, value) in inputs.items():
        sh.setInputValue(name, value, mx_type)
    doc.addMaterialNode("M", sh)
    return doc


@pytest.mark.parametrize("category", SHADING_MODELS)
def test_every_shading_model_expands_to_pbrlib_closures(category):
    compiled = compile_material(_doc_with(category), "M")
    info = compiled.describe()
    assert info["lobes_kept"], f"{category} expanded to no lobes"
    # After expansion only native operators remain: no node of the shading model's own category.
    assert all(n.category != category for n in compiled.graph.nodes)
    assert not info["spatial_inputs"] and not info["textures"]


def test_default_standard_surface_keeps_only_its_real_lobes():
    info = compile_material(_doc_with("standard_surface"), "M").describe()
    assert sorted(k["closure"] for k in info["lobes_kept"]) == ["dielectric_bsdf", "oren_nayar_diffuse_bsdf"]
    pruned = {k["node"].rsplit("/", 1)[-1]: k["reason"] for k in info["lobes_pruned"]}
    assert "weight folds to 0" in pruned["coat_bsdf"]
    assert "metalness_mix" in pruned["metal_bsdf"]
    assert "transmission" in pruned["transmission_bsdf"]
    assert info["approximations"] == []  # no emission, no subsurface by default


def test_enabling_a_lobe_keeps_it():
    info = compile_material(_doc_with("standard_surface", coat=("float", 1.0), metalness=("float", 1.0)), "M").describe()
    kept = sorted(k["closure"] for k in info["lobes_kept"])
    assert kept == ["conductor_bsdf", "dielectric_bsdf"]  # coat over metal; diffuse hidden by metalness 1


def test_constant_folding_through_stdlib_maths():
    doc = mx.createDocument()
    a = doc.addNode("constant", "a", "color3")
    a.setInputValue("value", mx.Color3(0.2, 0.4, 0.6))
    mul = doc.addNode("multiply", "mul", "color3")
    mul.setConnectedNode("in1", a)
    mul.setInputValue("in2", 0.5, "float")
    compiled, color = _diffuse_of(doc, mul)
    torch.testing.assert_close(color, torch.tensor([[0.1, 0.2, 0.3]]))  # folded at compile time
    assert compiled.spatial_nodes == []


def _diffuse_of(doc: mx.Document, colour: mx.Node):
    """Material M of ``doc``: a diffuse BSDF whose colour is ``colour``; (compiled, its colour value)."""
    diff = doc.addNode("oren_nayar_diffuse_bsdf", "d", "BSDF")
    diff.setConnectedNode("color", colour)
    surf = doc.addNode("surface", "s", "surfaceshader")
    surf.setConnectedNode("bsdf", diff)
    doc.addMaterialNode("M", surf)
    compiled = compile_material(doc, "M")
    leaf = compiled.program.leaves()[0]
    return compiled, compiled.evaluator.value(compiled.graph[leaf.node].inputs["color"], {})


def _scaled_diffuse(value: float, unit: str | None):
    """A diffuse surface whose colour is ``value`` (a float input with a distance ``unit``) times 0.5."""
    doc = mx.createDocument()
    mul = doc.addNode("multiply", "mul", "color3")
    mul.setInputValue("in1", mx.Color3(0.5, 0.5, 0.5))
    scale = mul.setInputValue("in2", value, "float")
    if unit:
        scale.setUnitType("distance")
        scale.setUnit(unit)
    return _diffuse_of(doc, mul)[1]


def test_distance_units_convert_to_metres():
    """A value with ``unit`` converts to metres as MaterialX's viewers set their generators up (80 cm is 0.8,
    1.6 km is 1600), by MaterialX's own converter; without ``unit`` it is used as written."""
    torch.testing.assert_close(_scaled_diffuse(80.0, "centimeter"), torch.full((1, 3), 0.4))
    torch.testing.assert_close(_scaled_diffuse(1.6, "kilometer"), torch.full((1, 3), 800.0))
    torch.testing.assert_close(_scaled_diffuse(0.8, None), torch.full((1, 3), 0.4))
    with pytest.raises(InputError, match="furlong"):
        _scaled_diffuse(1.0, "furlong")


def test_textured_material_splits_spatial_subgraph():
    path = shared_path("materialx", "resources", "Materials", "Examples", "StandardSurface",
                       "standard_surface_wood_tiled.mtlx")
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(path))
    compiled = compile_material(doc, None)
    info = compiled.describe()
    assert {t["file"].rsplit("/", 1)[-1] for t in info["textures"]} >= {"wood_color.jpg", "wood_roughness.jpg"}
    assert any(s["kind"] == "texcoord" for s in info["spatial_inputs"])
    assert any(p.endswith(".color") for p in info["varying_parameters"])
    # The spatial part is only what feeds live lobes; constant nodes are folded away.
    assert all(compiled.evaluator.spatial[i] for i in compiled.spatial_nodes)


def test_unsupported_node_names_node_nodedef_and_document(tmp_path):
    doc = mx.createDocument()
    hair = doc.addNode("chiang_hair_bsdf", "hair", "BSDF")
    surf = doc.addNode("surface", "s", "surfaceshader")
    surf.setConnectedNode("bsdf", hair)
    doc.addMaterialNode("M", surf)
    path = tmp_path / "hair.mtlx"
    mx.writeToXmlFile(doc, str(path))
    doc2 = mx.createDocument()
    mx.readFromXmlFile(doc2, str(path))
    with pytest.raises(UnsupportedNodeError) as err:
        compile_material(doc2, "M")
    msg = str(err.value)
    assert "hair" in msg and "ND_chiang_hair_bsdf" in msg and "hair.mtlx" in msg


def test_material_without_surface_shader_is_bad_input():
    doc = mx.createDocument()
    doc.addNode("surfacematerial", "M", "material")
    with pytest.raises(InputError, match="no surfaceshader"):
        compile_material(doc, "M")


def test_missing_texture_names_path_and_node(tmp_path):
    doc = mx.createDocument()
    img = doc.addNode("image", "albedo_tex", "color3")
    img.setInputValue("file", str(tmp_path / "nope.png"), "filename")
    sh = doc.addNode("standard_surface", "sh", "surfaceshader")
    sh.setConnectedNode("base_color", img)
    doc.addMaterialNode("M", sh)
    with pytest.raises(InputError) as err:
        compile_material(doc, "M")
    assert "nope.png" in str(err.value) and "albedo_tex" in str(err.value)
