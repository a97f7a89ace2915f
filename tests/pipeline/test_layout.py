"""Where a conversion writes (``mtlx2neural.pipeline.layout``, ``.lock``), through the real CLI.

Every refusal must come before any training: exit 2, a message naming the path and
saying to choose another ``-o``, and the input folder byte-identical (including the
input file, its sublayers and textures). Conversions that do run use the real
trainer for a step or none (``--iterations 0 --allow-untrained``): what is checked is
where files land and what the layer records, not quality.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from cli_helpers import assert_clean_input_error, run_cli, snapshot  # noqa: E402  (the CLI tests' helpers)
from conftest import SIMPLE_MTLX, unprivileged_prefix
from hypothesis import given, settings
from hypothesis import strategies as st

from mtlx2neural.pipeline.layout import (
    FOLDER_MARKER,
    material_folder,
    material_folders,
    resolve_output,
)
from mtlx2neural.pipeline.lock import output_lock

# --flagged neural: these models fail the quality gate (untrained or one step); the tests check the layout and
# the neural variant the layer authors, which is then the one selected.
FAST = ("--iterations", "1", "--batch", "64", "--quiet", "--device", "cpu", "--workers", "1", "--flagged", "neural")
UNTRAINED = ("--iterations", "0", "--allow-untrained", "--batch", "64", "--quiet", "--device", "cpu",
             "--workers", "1", "--flagged", "neural")


def stage_with(path: Path, materials: dict[str, tuple], sublayer: str | None = None) -> None:
    """A USD stage with one bound triangle per Material path of ``materials`` (path -> base colour)."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

    stage = Usd.Stage.CreateNew(str(path))
    if sublayer:
        stage.GetRootLayer().subLayerPaths.append(sublayer)
    UsdGeom.Xform.Define(stage, "/World")
    for k, (mat_path, color) in enumerate(materials.items()):
        mesh = UsdGeom.Mesh.Define(stage, f"/World/Geo{k}")
        mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
        mesh.CreateFaceVertexCountsAttr([3])
        mesh.CreateFaceVertexIndicesAttr([0, 1, 2])
        mat = UsdShade.Material.Define(stage, mat_path)
        shader = UsdShade.Shader.Define(stage, f"{mat_path}/SR")
        shader.CreateIdAttr("ND_standard_surface_surfaceshader")
        shader.CreateInput("base_color", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*color))
        out = shader.CreateOutput("out", Sdf.ValueTypeNames.Token)
        mat.CreateOutput("mtlx:surface", Sdf.ValueTypeNames.Token).ConnectToSource(out)
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    stage.GetRootLayer().Save()


def layer_record(layer: Path) -> dict:
    from pxr import Sdf

    return dict(Sdf.Layer.OpenAsAnonymous(str(layer)).customLayerData)["mtlx2neural"]


# ----------------------------------------------------------------------------- material folders


def test_material_folders_of_the_colliding_pair_differ():
    # The pair that shared one folder when '/' became '_'.
    a, b = material_folder("/World/Looks_A/Paint"), material_folder("/World/Looks/A_Paint")
    assert a != b
    assert (a, b) == ("World.Looks_A.Paint", "World.Looks.A_Paint")  # still readable


_NAME = st.lists(st.text(alphabet=st.characters(codec="utf-8", exclude_characters="/\0"), min_size=1, max_size=12),
                 min_size=1, max_size=4).map(lambda parts: "/" + "/".join(parts))


@settings(max_examples=300, deadline=None, derandomize=True)
@given(_NAME, _NAME)
def test_material_folder_is_injective_and_a_plain_file_name(a, b):
    fa, fb = material_folder(a), material_folder(b)
    assert (fa == fb) == (a == b)
    for f in (fa, fb):
        assert "/" not in f and "\\" not in f and f not in (".", "..") and not f.startswith(".")
        assert len(f.encode()) <= 255


def test_material_folders_stay_distinct_on_case_insensitive_file_systems():
    folders = material_folders(["/World/Red", "/World/red", "/World/Blue"])
    assert len({f.lower() for f in folders.values()}) == 3
    assert folders["/World/Blue"] == "World.Blue"  # no hash where nothing collides


@pytest.mark.slow
def test_convert_keeps_the_colliding_pair_apart(tmp_path, capsys):
    red, blue = "/World/Looks_A/Paint", "/World/Looks/A_Paint"
    asset = tmp_path / "pair.usda"
    stage_with(asset, {red: (0.9, 0.05, 0.05), blue: (0.05, 0.05, 0.9)})
    code, _, err = run_cli(capsys, asset, *UNTRAINED)
    assert code == 0, err
    out = tmp_path / "pair_neural"
    for name in (red, blue):
        summary = json.loads((out / material_folder(name) / "summary.json").read_text())
        assert summary["material"] == name
    record = layer_record(tmp_path / "pair_neural.usda")["materials"]
    assert record[red]["folder"] != record[blue]["folder"]
    assert record[red]["sourceHash"] != record[blue]["sourceHash"]  # red and blue are different materials
    from pxr import Usd

    stage = Usd.Stage.Open(str(tmp_path / "pair_neural.usda"))
    weights = {p: stage.GetPrimAtPath(f"{p}/NeuralBSDF").GetAttribute("inputs:weights").Get().resolvedPath
               for p in (red, blue)}
    assert weights[red] != weights[blue] and all(Path(w).is_file() for w in weights.values())


# ----------------------------------------------------------------------------- -o: folder or layer


def test_o_accepts_a_layer_path_and_a_layer_of_another_input_is_not_replaced(tmp_path, capsys):
    a, b = tmp_path / "a.mtlx", tmp_path / "b.mtlx"
    a.write_text(SIMPLE_MTLX)
    b.write_text(SIMPLE_MTLX)
    layer = tmp_path / "out" / "baked.usda"
    code, _, err = run_cli(capsys, a, "-o", layer, *UNTRAINED)
    assert code == 0, err
    assert layer.is_file() and not (tmp_path / "out" / "baked.usda.usda").exists()
    assert (tmp_path / "out" / "baked" / "Red" / "neural" / "weights.bin").is_file()
    assert resolve_output(a, "x/y.usdc").layer.name == "y.usdc"
    # The same output for another input: refused, both by the layer path and by the folder.
    before = snapshot(tmp_path)
    for out in (layer, tmp_path / "out" / "baked"):
        code, text, err = run_cli(capsys, b, "-o", out, *UNTRAINED)
        assert_clean_input_error(code, text, err, "written for another input", str(a))
    assert snapshot(tmp_path) == before


# ----------------------------------------------------------------------------- the input is never modified


def _scene(tmp_path: Path) -> Path:
    """A stage that sublayers base.usda, beside a texture it does not use."""
    base = tmp_path / "scene" / "base.usda"
    base.parent.mkdir()
    base.write_text("#usda 1.0\n")
    asset = tmp_path / "scene" / "scene.usda"
    stage_with(asset, {"/World/Looks/Red": (0.8, 0.1, 0.1)}, sublayer="./base.usda")
    return asset


OVERWRITES = {
    "layer is the input (-o scene)": lambda d: d / "scene",
    "layer is the input (-o scene.usda)": lambda d: d / "scene.usda",
    "layer is a sublayer (-o base)": lambda d: d / "base",
    "layer is a sublayer (-o base.usda)": lambda d: d / "base.usda",
    "folder holds the input (-o .)": lambda d: d,
    "folder holds the input (-o ..)": lambda d: d.parent,
    "layer is a foreign file": lambda d: d / "notes.usda",
    "folder holds foreign files": lambda d: d / "foreign",
    "folder is a file": lambda d: d / "readme.txt",
}


@pytest.mark.parametrize("case", sorted(OVERWRITES))
def test_no_output_path_lands_on_the_input_or_foreign_files(case, tmp_path, capsys):
    asset = _scene(tmp_path)
    d = asset.parent
    (d / "notes.usda").write_text("#usda 1.0\n(\n    doc = \"someone else's layer\"\n)\n")
    (d / "foreign").mkdir()
    (d / "foreign" / "data.txt").write_text("keep me")
    (d / "readme.txt").write_text("keep me")
    before = snapshot(tmp_path)
    out = OVERWRITES[case](d)
    code, out_text, err = run_cli(capsys, asset, "-o", out, *FAST)
    assert_clean_input_error(code, out_text, err, "choose another output with -o")
    assert snapshot(tmp_path) == before  # nothing written, nothing changed


def test_a_symlink_to_the_input_is_the_input(tmp_path, capsys):
    asset = _scene(tmp_path)
    link = tmp_path / "alias.usda"
    link.symlink_to(asset)
    before = snapshot(tmp_path)
    code, out, err = run_cli(capsys, asset, "-o", link, *FAST)
    assert_clean_input_error(code, out, err, "would overwrite the input")
    assert snapshot(tmp_path) == before


def test_an_unwritable_output_is_found_before_training(tmp_path, capsys):
    asset = tmp_path / "red.mtlx"
    asset.write_text(SIMPLE_MTLX)
    (tmp_path / "plain_file").write_text("x")
    code, out, err = run_cli(capsys, asset, "-o", tmp_path / "plain_file" / "out", *FAST)
    assert_clean_input_error(code, out, err, "cannot write there", "plain_file")


@pytest.mark.skipif(not hasattr(os, "geteuid"), reason="needs POSIX permissions")
def test_a_read_only_folder_is_found_before_training(tmp_path):
    """A folder without write permission (as root, the CLI runs without the capability that
    overrides permissions: conftest.unprivileged_prefix)."""
    prefix = unprivileged_prefix(tmp_path)
    asset = tmp_path / "red.mtlx"
    asset.write_text(SIMPLE_MTLX)
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        r = subprocess.run([*prefix, sys.executable, "-m", "mtlx2neural.cli", str(asset), "-o", str(locked / "out"),
                            *FAST], capture_output=True, text=True, timeout=300, cwd=tmp_path, check=False)
        assert r.returncode == 2, r.stderr
        assert "cannot write there" in r.stderr and "Permission denied" in r.stderr, r.stderr
        assert "Traceback" not in r.stderr
        assert not list(locked.iterdir())
    finally:
        locked.chmod(0o755)


# ----------------------------------------------------------------------------- incremental layers


@pytest.mark.slow
def test_a_material_rerun_keeps_the_other_materials(tmp_path, capsys):
    asset = tmp_path / "two.usda"
    stage_with(asset, {"/World/Looks/Red": (0.8, 0.1, 0.1), "/World/Looks/Blue": (0.1, 0.1, 0.8)})
    assert run_cli(capsys, asset, *UNTRAINED)[0] == 0
    layer = tmp_path / "two_neural.usda"
    first = layer_record(layer)["materials"]
    assert sorted(first) == ["/World/Looks/Blue", "/World/Looks/Red"]
    code, out, err = run_cli(capsys, asset, *UNTRAINED, "--material", "Red", "--force", "--seed", "3")
    assert code == 0, err
    assert "kept from earlier runs: /World/Looks/Blue" in out
    second = layer_record(layer)["materials"]
    assert second["/World/Looks/Blue"] == first["/World/Looks/Blue"]
    assert second["/World/Looks/Red"]["sourceHash"] != first["/World/Looks/Red"]["sourceHash"]  # seed 3
    from pxr import Usd

    stage = Usd.Stage.Open(str(layer))
    for path in first:
        prim = stage.GetPrimAtPath(path)
        assert prim.GetVariantSets().GetVariantSelection("neuralMaterial") == "neural"
        assert stage.GetPrimAtPath(f"{path}/NeuralBSDF").GetAttribute("inputs:weights").Get().resolvedPath


# ----------------------------------------------------------------------------- one run at a time


def test_a_second_run_on_a_held_output_exits_2_naming_the_holder(tmp_path, capsys):
    asset = tmp_path / "red.mtlx"
    asset.write_text(SIMPLE_MTLX)
    out = tmp_path / "red_neural"
    with output_lock(out):
        code, text, err = run_cli(capsys, asset, *FAST)
    assert_clean_input_error(code, text, err, "another mtlx2neural run is writing", f"pid {os.getpid()}")
    assert not any(p.name == "Red" for p in out.iterdir())
    with output_lock(out):  # released when the holder's block ended: the next run may take it
        assert (out / FOLDER_MARKER).is_file()  # the refused run had checked and marked the folder
