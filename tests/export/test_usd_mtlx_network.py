"""The export's MaterialX node and the neural variant's MaterialX network and UsdPreviewSurface fallback.

A one-material ``.mtlx`` input (nothing in the input shadows the variant's outputs) and the
sample USD scene (whose Materials connect ``outputs:mtlx:surface`` / ``outputs:surface``
themselves: the layer takes them over through the ``NeuralSwitch`` NodeGraph,
:mod:`mtlx2neural.export.usd_switch`). Trainings are tiny (30 steps): these tests
check files, prims and connections, not fidelity.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import MaterialX as mx
import numpy as np
import pytest
from conftest import SIMPLE_MTLX
from usd_validation import VALIDATE  # noqa: E402  (USD's validators in a fresh process)

from mtlx2neural.codegen.materialx_node import (
    generate_node_shader,
    latent_atlas,
    node_names,
)
from mtlx2neural.graph.library import with_libraries
from mtlx2neural.imaging.mip_chain import read_mip_chain
from mtlx2neural.pipeline.convert import convert_asset
from mtlx2neural.pipeline.inspection import inspect_asset
from mtlx2neural.pipeline.options import ConvertOptions
from mtlx2neural.train.config import preset

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "samples" / "layered_spheres.usda"
TINY = preset("fast", iterations=30, batch=256, seed=0)


@pytest.fixture(scope="module")
def red(tmp_path_factory):
    folder = tmp_path_factory.mktemp("red")
    asset = folder / "red.mtlx"
    asset.write_text(SIMPLE_MTLX)
    summaries = convert_asset(asset, ConvertOptions(train=TINY, progress=False, device="cpu"))
    return {"asset": asset, "summary": summaries[0], "usda": Path(summaries[0].usd),
            "export": folder / "red_neural" / "Red" / "neural"}


@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sample")
    asset = folder / SAMPLE.name
    shutil.copyfile(SAMPLE, asset)
    author_preview(asset, "/World/Looks/CarPaint")
    summaries = convert_asset(asset, ConvertOptions(train=TINY, progress=False, device="cpu"))
    return {"asset": asset, "summaries": summaries, "usda": Path(summaries[0].usd),
            "out": folder / "layered_spheres_neural"}


def author_preview(asset: Path, material: str) -> None:
    """Give ``material`` of the stage ``asset`` (a MaterialX network on ``outputs:mtlx:surface``) an authored
    UsdPreviewSurface on its universal ``outputs:surface``, as pipelines do for viewers without MaterialX:
    then both its terminal outputs are the input's own (Plastic connects only ``outputs:surface``)."""
    from pxr import Sdf, Usd, UsdShade

    stage = Usd.Stage.Open(str(asset))
    shader = UsdShade.Shader.Define(stage, f"{material}/AuthoredPreview")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set((0.6, 0.1, 0.1))
    UsdShade.Material(stage.GetPrimAtPath(material)).CreateSurfaceOutput().ConnectToSource(
        shader.CreateOutput("surface", Sdf.ValueTypeNames.Token))
    stage.Save()


def _document(path: Path):
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(path))
    return doc


def _material(usda: Path, prim: str, variant: str = "neural"):
    from pxr import Usd, UsdShade

    stage = Usd.Stage.Open(str(usda))
    p = stage.GetPrimAtPath(prim)
    p.GetVariantSets().GetVariantSet("neuralMaterial").SetVariantSelection(variant)
    return stage, UsdShade.Material(p)


@pytest.mark.slow
def test_every_converted_material_has_a_valid_node_that_generates(red, sample):
    exports = [red["export"]] + [sample["out"] / n / "neural" for n in ("World.Looks.CarPaint", "World.Looks.Plastic")]
    for export, name in zip(exports, ["Red", "/World/Looks/CarPaint", "/World/Looks/Plastic"]):
        n = node_names(name)
        mtlx = export / "materialx" / n.mtlx
        assert mtlx.is_file() and (mtlx.parent / n.glsl).is_file() and (mtlx.parent / n.slang).is_file()
        doc = _document(mtlx)
        ok, message = with_libraries(doc).validate()
        assert ok, message
        node = doc.getNode(n.node)
        for k in range(2):  # 8 latent channels: two atlases beside the document, from latents_0/1.exr
            value = node.getInputValue(f"latent{k}")
            assert value == f"latent_atlas_{k}.exr"
            atlas = read_mip_chain(mtlx.parent / value)
            assert len(atlas) == 1  # one level: a viewer's own MIP maps are never read by the node
            np.testing.assert_array_equal(atlas[0], latent_atlas(read_mip_chain(export / f"latents_{k}.exr")))
        assert (export / f"NeuralMaterial_{n.ident}.slang").is_file()  # the Slang module is not overwritten
        shader = generate_node_shader(mtlx, "genglsl")
        assert n.function in shader.getSourceCode("pixel")


def test_mtlx_network_in_the_neural_variant(red):
    from pxr import UsdShade

    n = node_names("Red")
    mtlx = red["export"] / "materialx" / n.mtlx
    stage, mat = _material(red["usda"], "/Materials/Red")
    surface = mat.ComputeSurfaceSource("mtlx")[0]
    assert surface.GetPath() == f"/Materials/Red/{n.surface}" and surface.GetShaderId() == "ND_surface"
    (src,) = surface.GetInput("bsdf").GetConnectedSources()[0]
    bsdf = UsdShade.Shader(src.source.GetPrim())
    assert bsdf.GetShaderId() == n.nodedef == _document(mtlx).getNodeDefs()[0].getName()
    for k in range(2):
        asset = bsdf.GetInput(f"latent{k}").Get()
        assert asset.path.startswith("./") and Path(asset.resolvedPath) == mtlx.parent / f"latent_atlas_{k}.exr"
    (tc,) = bsdf.GetInput("texcoord").GetConnectedSources()[0]
    reader = UsdShade.Shader(tc.source.GetPrim())
    assert reader.GetShaderId() == "ND_geompropvalue_vector2" and reader.GetInput("geomprop").Get() == "st"
    record = stage.GetRootLayer().customLayerData["mtlx2neural"]
    doc_rel = record["materials"]["Red"]["mtlxDocument"]
    assert (red["usda"].parent / doc_rel).resolve() == mtlx
    assert list(record["mtlxPluginSearchPaths"]) == [doc_rel.rsplit("/", 1)[0]]
    assert "PXR_MTLX_PLUGIN_SEARCH_PATHS" in stage.GetRootLayer().documentation
    # the original variant: the input's MaterialX material only
    stage, mat = _material(red["usda"], "/Materials/Red", "original")
    original = mat.ComputeSurfaceSource("mtlx")[0]
    assert original.GetSourceAsset("mtlx").path == "./red.mtlx" and original.GetSourceAssetSubIdentifier("mtlx") == "Red"
    assert not mat.ComputeSurfaceSource()[0] and not stage.GetPrimAtPath(f"/Materials/Red/{n.node}")


def test_preview_surface_and_its_flip(red):
    from pxr import UsdShade

    stage, mat = _material(red["usda"], "/Materials/Red")
    surf = mat.ComputeSurfaceSource()[0]  # the universal render context
    assert surf.GetPath() == "/Materials/Red/NeuralPreview" and surf.GetShaderId() == "UsdPreviewSurface"
    for name in ("diffuseColor", "roughness", "metallic", "normal"):
        (src,) = surf.GetInput(name).GetConnectedSources()[0]
        tex = UsdShade.Shader(src.source.GetPrim())
        assert Path(tex.GetInput("file").Get().resolvedPath) == red["export"] / "preview" / f"{name}.exr"
    flip = red["summary"].preview_flip
    assert math.isfinite(flip) and flip > 0
    # float32 attribute against the summary's 4-decimal value
    assert mat.GetPrim().GetAttribute("neural:metrics:previewFlip").Get() == pytest.approx(flip, abs=1e-6)
    assert (red["export"].parent / "analytic_baseline.pt").is_file()
    assert red["summary"].preview["iterations"] > 0


def test_preview_flip_for_every_sample_material(sample):
    """CarPaint's fitted fallback has a measured FLIP; Plastic's fallback is its own UsdPreviewSurface, the
    reference itself (FLIP 0, nothing fitted, the export says so)."""
    by_name = {s.material: s for s in sample["summaries"]}
    assert set(by_name) == {"/World/Looks/CarPaint", "/World/Looks/Plastic"}
    for s in sample["summaries"]:
        own = s.material == "/World/Looks/Plastic"
        assert math.isfinite(s.preview_flip) and (s.preview_flip == 0 if own else s.preview_flip > 0)
        assert bool(s.preview.get("own")) == own and (s.preview["file"] is None) == own
        stage, mat = _material(sample["usda"], s.material)
        attr = mat.GetPrim().GetAttribute("neural:metrics:previewFlip").Get()
        assert attr == pytest.approx(s.preview_flip, abs=1e-6)
    assert not (sample["out"] / "World.Looks.Plastic" / "analytic_baseline.pt").exists()
    assert any("own UsdPreviewSurface stays its fallback" in n for n in by_name["/World/Looks/Plastic"].export_notes)


def test_an_input_preview_surface_stays_its_own_fallback(sample):
    """Plastic's universal surface is the input's UsdPreviewSurface: in both variants the universal render
    context resolves to that shader, untouched (no switch, no NeuralPreview); the ``mtlx`` context switches
    to the neural node in ``neural`` only."""
    from pxr import Usd

    name = "/World/Looks/Plastic"
    source = Usd.Stage.Open(str(sample["asset"]))
    own = source.GetPrimAtPath(f"{name}/Preview")
    for variant in ("neural", "original"):
        stage, mat = _material(sample["usda"], name, variant)
        assert mat.ComputeSurfaceSource("")[0].GetPath() == own.GetPath(), variant
        mtlx = mat.ComputeSurfaceSource("mtlx")[0]
        assert (mtlx.GetShaderId() == "ND_surface") == (variant == "neural"), variant
        assert not stage.GetPrimAtPath(f"{name}/NeuralPreview") and not stage.GetPrimAtPath(f"{name}/NeuralSwitch")
        for attr in own.GetAttributes():  # the shader composes as authored
            assert stage.GetAttributeAtPath(attr.GetPath()).Get() == attr.Get(), attr.GetPath()
    said = {m["material"]: m["fallback"] for m in inspect_asset(sample["asset"])["materials"]}
    assert "own UsdPreviewSurface" in said[name] and "fitted" in said["/World/Looks/CarPaint"]


def test_neural_variant_wins_over_the_inputs_own_outputs(sample):
    """CarPaint connects ``outputs:mtlx:surface`` and (``author_preview``) ``outputs:surface`` itself: with
    ``neural`` selected, both render contexts still resolve to the neural networks, through the switch that
    the layer connects outside the variants; in both variants every switch connection is one UsdShade
    allows (encapsulation)."""
    from pxr import Sdf, UsdShade

    name = "/World/Looks/CarPaint"
    for own in ("outputs:mtlx:surface", "outputs:surface"):
        n = node_names(name)
        stage, mat = _material(sample["usda"], name)
        assert mat.ComputeSurfaceSource("mtlx")[0].GetPath() == f"{name}/{n.surface}"
        assert mat.ComputeSurfaceSource("mtlx")[0].GetShaderId() == "ND_surface"
        preview = mat.ComputeSurfaceSource("")[0]
        assert preview.GetPath() == f"{name}/NeuralPreview" and preview.GetShaderId() == "UsdPreviewSurface"
        # the Material's own output, in the layer outside the variants, names the switch
        spec = stage.GetRootLayer().GetAttributeAtPath(Sdf.Path(name).AppendProperty(own))
        port = own[len("outputs:"):].replace(":", "_")
        assert list(spec.connectionPathList.explicitItems) == [Sdf.Path(f"{name}/NeuralSwitch.outputs:{port}")]
        for variant in ("neural", "original"):
            stage, mat = _material(sample["usda"], name, variant)
            switch = UsdShade.NodeGraph(stage.GetPrimAtPath(f"{name}/NeuralSwitch"))
            assert switch and port in [o.GetBaseName() for o in switch.GetOutputs()]
            for attr in (switch.GetInput(port).GetAttr(), switch.GetOutput(port).GetAttr()):
                (target,) = attr.GetConnections()
                wrap = UsdShade.Input(attr) if UsdShade.Input.IsInput(attr) else UsdShade.Output(attr)
                assert UsdShade.ConnectableAPI.CanConnect(wrap, stage.GetAttributeAtPath(target)), (variant, attr)
    notes = " ".join(n for s in sample["summaries"] for n in s.export_notes)
    assert "outputs:" not in notes  # nothing shadowed, nothing to note


def test_no_preview_fallback_at_zero_preview_iterations(tmp_path):
    """``preview_iterations = 0``: no analytic fit, no NeuralPreview shader, no previewFlip; the note says why."""
    asset = tmp_path / "red.mtlx"
    asset.write_text(SIMPLE_MTLX)
    cfg = preset("fast", iterations=30, batch=256, seed=0, preview_iterations=0)
    (summary,) = convert_asset(asset, ConvertOptions(train=cfg, progress=False, device="cpu"))
    assert summary.preview_flip is None and summary.preview is None
    assert not (tmp_path / "red_neural" / "Red" / "analytic_baseline.pt").exists()
    assert not (tmp_path / "red_neural" / "Red" / "neural" / "preview").exists()
    stage, mat = _material(Path(summary.usd), "/Materials/Red")
    assert not stage.GetPrimAtPath("/Materials/Red/NeuralPreview") and not mat.ComputeSurfaceSource("")[0]
    assert not mat.GetPrim().GetAttribute("neural:metrics:previewFlip")
    assert mat.ComputeSurfaceSource("mtlx")[0].GetPath() == f"/Materials/Red/{node_names('Red').surface}"
    assert any("preview_iterations = 0" in n for n in summary.export_notes)




def test_usd_validation(red):
    proc = subprocess.run([sys.executable, "-c", VALIDATE, str(red["usda"])], capture_output=True, text=True,
                          timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr
    errors = json.loads(proc.stdout.strip().splitlines()[-1])[str(red["usda"])]
    # usd-core has no UsdMtlx, whose Sdr discovery would know the MaterialX nodedefs: their ids are
    # missing from its registry. They must be exactly the network's three ids, each a real nodedef
    # (the standard library's, or the exported document's); any other error fails.
    n = node_names("Red")
    ids = {"ND_surface", "ND_geompropvalue_vector2", n.nodedef}
    doc = with_libraries(_document(red["export"] / "materialx" / n.mtlx))
    assert all(doc.getNodeDef(i) for i in ids)
    missing = {e[2].split("'")[1] for e in errors if e[0] == "MissingShaderIdInRegistry"}
    assert missing == ids
    assert [e for e in errors if e[0] not in ("MissingShaderIdInRegistry", "MissingSourceTypeInRegistry")] == []
