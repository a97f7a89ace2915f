"""An open Usd.Stage as input: the private view, unsaved layers, and the flattened snapshot."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from conftest import write_float_image
from materials import SIMPLE_MTLX, usd_painted_ball
from pxr import Sdf, Usd, UsdGeom

from mtlx2neural.scene import find_material, load_asset
from mtlx2neural.scene.dependencies import canonical, input_files
from mtlx2neural.scene.snapshot import flatten, unsaved_layers, write_snapshot
from mtlx2neural.scene.texel_density import open_stage_for, surface_density

LOOKS = usd_painted_ball("""
    float inputs:base = 0.8
    color3f inputs:base_color.connect = </World/Looks/Paint/Found.outputs:out>
    float inputs:specular_roughness.connect = </World/Looks/Paint/Missing.outputs:out>
""", extra_shaders='            def Shader "Found"\n            {\n                uniform token info:id = "ND_image_color3"\n                asset inputs:file = @./tex/found.exr@\n                color3f outputs:out\n            }\n            def Shader "Missing"\n            {\n                uniform token info:id = "ND_image_float"\n                asset inputs:file = @./tex/missing.exr@\n                float outputs:out\n            }\n')
PAINT = "/World/Looks/Paint"


def _files(tmp_path: Path) -> Path:
    """``parts/looks.usda`` (relative texture paths: one file exists, one does not)."""
    (tmp_path / "parts" / "tex").mkdir(parents=True)
    write_float_image(tmp_path / "parts" / "tex" / "found.exr",
                      np.random.default_rng(3).random((4, 4, 3)).astype(np.float32))
    (tmp_path / "parts" / "looks.usda").write_text(LOOKS)
    return tmp_path / "parts" / "looks.usda"


def _filenames(document) -> dict[str, str]:
    return {e.getParent().getName(): e.getValueString() for e in document.traverseTree()
            if e.getCategory() == "input" and e.getAttribute("type") == "filename"}


def test_flatten_anchors_every_asset_path_as_the_converter_does(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # an anonymous layer's relative path is anchored here
    looks = _files(tmp_path)
    stage = Usd.Stage.CreateInMemory()
    stage.GetRootLayer().subLayerPaths.append(str(looks))
    # An in-memory opinion with a relative path: an anonymous layer has no folder of its own.
    stage.GetAttributeAtPath(f"{PAINT}/Missing.inputs:file").Set(Sdf.AssetPath("./mem/rough.exr"))
    converted = _filenames(find_material(stage, PAINT).document)

    flat = flatten(stage)
    found = flat.GetAttributeAtPath(f"{PAINT}/Found.inputs:file").default.path
    missing = flat.GetAttributeAtPath(f"{PAINT}/Missing.inputs:file").default.path
    # Flatten anchors the resolvable path itself; the in-memory one it leaves relative
    # (it would then resolve against the snapshot's folder), so flatten anchors it.
    assert stage.Flatten().GetAttributeAtPath(f"{PAINT}/Missing.inputs:file").default.path == "./mem/rough.exr"
    assert found == str(tmp_path / "parts" / "tex" / "found.exr")
    assert missing == os.path.normpath(str(tmp_path / "mem" / "rough.exr"))
    assert set(converted.values()) == {found, missing}  # the same paths the MaterialX document holds

    # Written and read back, the snapshot gives the converted document again.
    snap = write_snapshot(flat, tmp_path / "out" / "snap.usda")
    assert sorted(p.name for p in snap.parent.iterdir()) == ["snap.usda"]  # no temporary left
    again = find_material(snap, PAINT)
    assert _filenames(again.document) == converted
    assert again.source_file == str(snap) and again.network


def test_unsaved_layers(tmp_path):
    looks = _files(tmp_path)
    stage = Usd.Stage.Open(str(looks))
    assert unsaved_layers(stage) == []  # equals its files
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        stage.GetAttributeAtPath(f"{PAINT}/SR.inputs:base").Set(0.3)
    assert unsaved_layers(stage) == [stage.GetSessionLayer().identifier]
    stage.GetSessionLayer().Clear()
    stage.GetAttributeAtPath(f"{PAINT}/SR.inputs:base").Set(0.5)  # the root (file) layer, unsaved
    assert unsaved_layers(stage) == [str(looks)]
    assert unsaved_layers(Usd.Stage.CreateInMemory()) == []  # empty anonymous layers hold nothing


def test_stage_input_honours_session_edits_and_leaves_the_stage_alone(tmp_path):
    looks = _files(tmp_path)
    (tmp_path / "lib").mkdir()
    (tmp_path / "lib" / "simple.mtlx").write_text(SIMPLE_MTLX)
    stage = Usd.Stage.Open(str(looks))
    # A .mtlx reference (placeholders go to the view's session layer, not the caller's).
    stage.DefinePrim("/World/MX").GetReferences().AddReference(str(tmp_path / "lib" / "simple.mtlx"), "/MaterialX")
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        stage.GetAttributeAtPath(f"{PAINT}/SR.inputs:base").Set(0.3)
    session = stage.GetSessionLayer().ExportToString()

    scene = load_asset(stage)
    (paint,) = [m for m in scene.materials if m.name == PAINT]
    sr = paint.document.getNode("SR")
    assert abs(sr.getInput("base").getValue() - 0.3) < 1e-7  # float32 0.3 read as a double
    assert scene.asset == str(looks)
    assert [n for n, _ in scene.skipped] == ["/World/MX/Materials/Red"]  # bound to nothing
    assert stage.GetSessionLayer().ExportToString() == session
    assert not stage.GetPrimAtPath("/World/MX/Materials/Red")

    # The input closure of an open stage: its files, not its anonymous layers.
    files = input_files(stage, scene.materials)
    assert canonical(looks) in files and canonical(tmp_path / "parts" / "tex" / "found.exr") in files
    assert canonical(tmp_path / "lib" / "simple.mtlx") in files
    assert not any("anon:" in str(f) for f in files)


def test_texel_density_measures_the_open_stage_as_composed():
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    mesh = UsdGeom.Mesh.Define(stage, "/Quad")  # 1 m x 1 m, UVs 0..1: one metre per UV unit
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                            UsdGeom.Tokens.vertex).Set([(0, 0), (1, 0), (1, 1), (0, 1)])
    with Usd.EditContext(stage, stage.GetSessionLayer()):  # scaled 3x in the session layer only
        UsdGeom.Xformable(mesh.GetPrim()).AddScaleOp().Set((3.0, 3.0, 3.0))
    # 9 m^2 over 1 UV unit^2: 3 m per UV unit (float32 points: exact for these small integers).
    assert surface_density(open_stage_for(stage), ["/Quad"]).metres_per_uv == 3.0
    assert not stage.GetSessionLayer().empty and stage.GetRootLayer().GetPrimAtPath("/Quad")
