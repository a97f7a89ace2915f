"""The command line: ``mtlx2neural inspect`` on real assets, and its bad-input paths.

Most tests call :func:`mtlx2neural.cli.main` in-process (stdout/stderr via
capsys); one runs the installed console script to prove the entry point works.
Bad input must exit 2, name the file (and node or prim) on stderr, print no
traceback and write nothing.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import shared_path

from mtlx2neural.cli import main

STD_SURFACE = ("materialx", "resources", "Materials", "Examples", "StandardSurface")

from cli_helpers import assert_clean_input_error, run_cli, snapshot  # noqa: E402,F401  (shared helpers)
from conftest import SIMPLE_MTLX  # noqa: E402  (a minimal material named Red)

# ----------------------------------------------------------------------------- helpers


def make_usd_stage(path: Path, *, bind: bool = True, surface_output: str | None = "mtlx:surface") -> None:
    """A Mesh bound to a MaterialX standard_surface Material, and an unbound second Material.

    ``surface_output`` is the Material's terminal (None: the bound Material has none).
    """
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Xform.Define(stage, "/World")
    UsdGeom.Scope.Define(stage, "/World/Looks")
    mesh = UsdGeom.Mesh.Define(stage, "/World/Ball")
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([3])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2])

    def material(mat_path: str, color, terminal: str | None) -> UsdShade.Material:
        mat = UsdShade.Material.Define(stage, mat_path)
        shader = UsdShade.Shader.Define(stage, f"{mat_path}/SR")
        shader.CreateIdAttr("ND_standard_surface_surfaceshader")
        shader.CreateInput("base_color", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*color))
        out = shader.CreateOutput("out", Sdf.ValueTypeNames.Token)
        if terminal is not None:
            mat.CreateOutput(terminal, Sdf.ValueTypeNames.Token).ConnectToSource(out)
        return mat

    red = material("/World/Looks/Red", (0.8, 0.1, 0.1), surface_output)
    material("/World/Looks/Unused", (0.1, 0.1, 0.8), "mtlx:surface")
    if bind:
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(red)
    stage.GetRootLayer().Save()


# ----------------------------------------------------------------------------- inspect: good input


def test_inspect_standard_surface_default_text(capsys):
    asset = shared_path(*STD_SURFACE, "standard_surface_default.mtlx")
    code, out, err = run_cli(capsys, "inspect", asset)
    assert code == 0, err
    assert "Traceback" not in err
    assert f"asset: {asset}" in out
    assert "material Default" in out
    kept = out.split("lobes kept:", 1)[1].split("lobes pruned:", 1)[0]
    assert "dielectric_bsdf" in kept and "oren_nayar_diffuse_bsdf" in kept
    pruned = out.split("lobes pruned:", 1)[1]
    for closure in ("sheen_bsdf", "conductor_bsdf", "subsurface_bsdf", "translucent_bsdf"):
        assert closure in pruned
    assert pruned.count("why: ") >= 4
    assert "why: weight folds to 0" in pruned
    assert "spatially uniform" in out


def test_inspect_standard_surface_default_json(capsys):
    asset = shared_path(*STD_SURFACE, "standard_surface_default.mtlx")
    code, out, err = run_cli(capsys, "inspect", asset, "--json")
    assert code == 0, err
    report = json.loads(out)
    assert report["asset"] == str(asset)
    assert report["skipped"] == []
    assert len(report["materials"]) == 1
    m = report["materials"][0]
    for key in ("lobes_kept", "lobes_pruned", "spatial_inputs", "textures", "bound_prims"):
        assert key in m, key
    assert m["material"] == "Default"
    assert {k["closure"] for k in m["lobes_kept"]} == {"dielectric_bsdf", "oren_nayar_diffuse_bsdf"}
    assert m["lobes_pruned"], "standard_surface defaults prune coat, sheen, metal, ..."
    for lobe in m["lobes_pruned"]:
        assert lobe["reason"].strip(), lobe
    assert m["spatial_inputs"] == [] and m["textures"] == [] and m["bound_prims"] == []

    # The text report and the JSON agree.
    code, text, _ = run_cli(capsys, "inspect", asset)
    assert code == 0
    for lobe in m["lobes_pruned"]:
        assert lobe["reason"] in text


def test_inspect_textured_lists_absolute_existing_textures(capsys):
    asset = shared_path(*STD_SURFACE, "standard_surface_wood_tiled.mtlx")
    code, out, err = run_cli(capsys, "inspect", asset, "--json")
    assert code == 0, err
    m = json.loads(out)["materials"][0]
    files = [t["file"] for t in m["textures"]]
    assert len(files) >= 2
    assert {os.path.basename(f) for f in files} >= {"wood_color.jpg", "wood_roughness.jpg"}
    for f in files:
        assert os.path.isabs(f) and os.path.isfile(f), f
        assert os.path.normpath(f) == f
    assert m["spatial_inputs"], "textures sampled by UV are a spatial input"
    assert m["varying_parameters"]

    code, text, _ = run_cli(capsys, "inspect", asset)
    assert code == 0
    assert "spatially varying:" in text
    for f in files:
        assert f in text


def test_inspect_usd_stage_bound_and_skipped(tmp_path, capsys):
    stage = tmp_path / "scene.usda"
    make_usd_stage(stage)
    code, out, err = run_cli(capsys, "inspect", stage, "--json")
    assert code == 0, err
    report = json.loads(out)
    assert [m["material"] for m in report["materials"]] == ["/World/Looks/Red"]
    red = report["materials"][0]
    assert red["bound_prims"] == ["/World/Ball"]
    assert red["source"] == str(stage)
    assert {k["closure"] for k in red["lobes_kept"]} == {"dielectric_bsdf", "oren_nayar_diffuse_bsdf"}
    assert len(report["skipped"]) == 1
    skipped = report["skipped"][0]
    assert skipped["material"] == "/World/Looks/Unused"
    assert "not bound" in skipped["reason"]

    code, text, _ = run_cli(capsys, "inspect", stage)
    assert code == 0
    assert "bound prims: /World/Ball" in text
    after_skipped = text.split("skipped:", 1)[1]
    assert "/World/Looks/Unused: not bound" in after_skipped


def test_inspect_material_filter(tmp_path, capsys):
    stage = tmp_path / "scene.usda"
    make_usd_stage(stage)
    for name in ("Red", "/World/Looks/Red"):
        code, out, err = run_cli(capsys, "inspect", stage, "--material", name, "--json")
        assert code == 0, err
        assert [m["material"] for m in json.loads(out)["materials"]] == ["/World/Looks/Red"]
    # Naming a material the scene skips is not an error: it is reported with the reason.
    code, out, err = run_cli(capsys, "inspect", stage, "--material", "Unused", "--json")
    assert code == 0, err
    report = json.loads(out)
    assert report["materials"] == []
    assert [s["material"] for s in report["skipped"]] == ["/World/Looks/Unused"]


def test_inspect_unknown_material_is_input_error(tmp_path, capsys):
    stage = tmp_path / "scene.usda"
    make_usd_stage(stage)
    before = snapshot(tmp_path)
    code, out, err = run_cli(capsys, "inspect", stage, "--material", "Nope")
    assert_clean_input_error(code, out, err, str(stage), "'Nope'", "/World/Looks/Red")
    assert snapshot(tmp_path) == before


# ----------------------------------------------------------------------------- inspect: bad input

from materials import HAIR_MTLX  # noqa: E402  (shared documents)

BAD_INPUTS = {
    # id: (file name, content, strings the message must contain besides the file path)
    "malformed-xml": (
        "broken.mtlx",
        (
            '<?xml version="1.0"?>\n<materialx version="1.39">\n'
            '  <standard_surface name="SR" type="surfaceshader">\n'
            "</materialx\n"
        ),
        ["not a readable MaterialX document"],
    ),
    "empty-mtlx": ("empty.mtlx", "", ["not a readable MaterialX document"]),
    "malformed-usd": (
        "broken.usda",
        '#usda 1.0\ndef Xform "World" {\n  def Mesh "m" (\n}\n',
        ["not a readable USD file"],
    ),
    "unsupported-node": ("hair.mtlx", HAIR_MTLX, ["'hair'", "ND_chiang_hair_bsdf"]),
    "unknown-category": (
        "foo.mtlx",
        HAIR_MTLX.replace("chiang_hair_bsdf", "foo_bsdf").replace('"hair"', '"x"'),
        ["'x'", "foo_bsdf"],
    ),
    "mtlx-no-surfaceshader": (
        "noshader.mtlx",
        (
            '<?xml version="1.0"?>\n<materialx version="1.39">\n'
            '  <standard_surface name="SR" type="surfaceshader" />\n'
            '  <surfacematerial name="M" type="material" />\n</materialx>\n'
        ),
        ["'M'", "surfaceshader"],
    ),
    "missing-texture": (
        "notex.mtlx",
        (
            '<?xml version="1.0"?>\n<materialx version="1.39">\n'
            '  <image name="img" type="color3">\n'
            '    <input name="file" type="filename" value="textures/does_not_exist.png" />\n'
            "  </image>\n"
            '  <standard_surface name="SR" type="surfaceshader">\n'
            '    <input name="base_color" type="color3" nodename="img" />\n'
            "  </standard_surface>\n"
            '  <surfacematerial name="M" type="material">\n'
            '    <input name="surfaceshader" type="surfaceshader" nodename="SR" />\n'
            "  </surfacematerial>\n</materialx>\n"
        ),
        ["does_not_exist.png", "'img'"],
    ),
    "unsupported-extension": ("material.txt", "hello\n", ["unsupported file type"]),
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_inspect_bad_input(case, tmp_path, capsys, monkeypatch):
    name, content, expected = BAD_INPUTS[case]
    asset = tmp_path / name
    asset.write_text(content)
    original = asset.read_bytes()
    monkeypatch.chdir(tmp_path)  # anything written relative to the cwd would land in the snapshot
    before = snapshot(tmp_path)
    for extra in ([], ["--json"]):
        code, out, err = run_cli(capsys, "inspect", asset, *extra)
        assert_clean_input_error(code, out, err, str(asset), *expected)
    assert snapshot(tmp_path) == before
    assert asset.read_bytes() == original


def test_inspect_missing_texture_message_is_absolute(tmp_path, capsys):
    name, content, _ = BAD_INPUTS["missing-texture"]
    asset = tmp_path / name
    asset.write_text(content)
    code, out, err = run_cli(capsys, "inspect", asset)
    assert_clean_input_error(code, out, err, str(tmp_path / "textures" / "does_not_exist.png"))


def test_inspect_missing_file(tmp_path, capsys, monkeypatch):
    (tmp_path / "other.mtlx").write_text(SIMPLE_MTLX)
    monkeypatch.chdir(tmp_path)
    before = snapshot(tmp_path)
    for name in ("missing.mtlx", "missing.usda"):
        asset = tmp_path / name
        code, out, err = run_cli(capsys, "inspect", asset)
        assert_clean_input_error(code, out, err, str(asset), "not found")
        assert not asset.exists()
    assert snapshot(tmp_path) == before


def test_inspect_usd_material_without_surface_terminal(tmp_path, capsys, monkeypatch):
    stage = tmp_path / "noterminal.usda"
    make_usd_stage(stage, surface_output=None)
    original = stage.read_bytes()
    monkeypatch.chdir(tmp_path)
    before = snapshot(tmp_path)
    code, out, err = run_cli(capsys, "inspect", stage)
    assert_clean_input_error(code, out, err, str(stage), "/World/Looks/Red", "outputs:mtlx:surface", "outputs:surface")
    assert snapshot(tmp_path) == before
    assert stage.read_bytes() == original


def test_inspect_shared_asset_with_missing_texture(capsys):
    # brass_color.jpg is known to be missing from ../shared (see its README).
    asset = shared_path(*STD_SURFACE, "standard_surface_brass_tiled.mtlx")
    if (asset.parents[3] / "Images" / "brass_color.jpg").exists():
        pytest.skip("brass_color.jpg is present; the missing-texture path is covered with tmp files")
    code, out, err = run_cli(capsys, "inspect", asset)
    assert_clean_input_error(code, out, err, str(asset), "brass_color.jpg", "N_img_color3")


# ----------------------------------------------------------------------------- conversion


def test_convert_trains_into_the_output_folder_and_leaves_the_input(tmp_path, capsys, monkeypatch):
    asset = tmp_path / "red.mtlx"
    asset.write_text(SIMPLE_MTLX)
    monkeypatch.chdir(tmp_path)
    before = snapshot(tmp_path)
    code, out, err = run_cli(capsys, asset, "--iterations", "20", "--batch", "256", "--quiet", "--device", "cpu")
    assert code == 0, err
    assert "Traceback" not in err
    outdir = tmp_path / "red_neural" / "Red"
    summary = json.loads((outdir / "summary.json").read_text())
    assert summary["steps"] == 20 and summary["material"] == "Red"
    assert (outdir / "checkpoint.pt").exists() and (outdir / "training_curves.csv").exists()
    # The input folder only gained the output folder; the input file is unchanged.
    after = {k: v for k, v in snapshot(tmp_path).items() if not str(k).startswith("red_neural")}
    assert after == before


def test_every_preset_is_a_choice_and_overrides_apply(capsys):
    """--preset takes every named preset (the choices come from PRESETS), the explicit flags
    override its fields, and an unknown name is a usage error (argparse: exit 2)."""
    import dataclasses

    from mtlx2neural.commands.convert import options_of
    from mtlx2neural.commands.parser import build_parser
    from mtlx2neural.train.config import PRESETS

    def parse(*argv):
        return build_parser()[0].parse_args(["convert", "a.usda", *argv])

    for name, cfg in PRESETS.items():
        assert options_of(parse("--preset", name)).train_config() == cfg
    args = parse("--preset", "standard", "--iterations", "20", "--seed", "3")
    assert options_of(args).train_config() == dataclasses.replace(PRESETS["standard"], iterations=20, seed=3)
    # standard is fast for longer: the same sampling and schedule shapes, 4x the steps of twice the rows
    # (8x fast's rows), the balance's gain of 0.3 it was measured with (and the preview fallback's fit at its
    # full 200 steps instead of fast's 100, FLIP probes 2x sparser, the environment head fitted for 2000
    # steps instead of 1000).
    assert PRESETS["standard"].preview_iterations == 2 * PRESETS["fast"].preview_iterations
    assert PRESETS["standard"].probe_every == 2 * PRESETS["fast"].probe_every
    assert PRESETS["standard"].environment_steps > PRESETS["fast"].environment_steps > 0
    assert (PRESETS["standard"].iterations * PRESETS["standard"].batch
            == 8 * PRESETS["fast"].iterations * PRESETS["fast"].batch)
    assert dataclasses.replace(PRESETS["standard"], iterations=PRESETS["fast"].iterations,
                               batch=PRESETS["fast"].batch, energy_gain=PRESETS["fast"].energy_gain,
                               preview_iterations=PRESETS["fast"].preview_iterations,
                               probe_every=PRESETS["fast"].probe_every,
                               environment_fraction=PRESETS["fast"].environment_fraction) == PRESETS["fast"]
    with pytest.raises(SystemExit) as exc:
        parse("--preset", "nope")
    assert exc.value.code == 2 and "standard" in capsys.readouterr().err


def test_convert_bad_input_is_exit_2(tmp_path, capsys):
    code, out, err = run_cli(capsys, tmp_path / "missing.usda", "--quiet")
    assert code == 2 and "missing.usda" in err and "Traceback" not in err
    assert not (tmp_path / "missing_neural").exists()


# ----------------------------------------------------------------------------- the installed entry point


def test_console_script_entry_point(tmp_path):
    exe = Path(sys.executable).with_name("mtlx2neural")
    script = str(exe) if exe.exists() else shutil.which("mtlx2neural")
    assert script, "the mtlx2neural console script is not installed"
    asset = tmp_path / "red.mtlx"
    asset.write_text(SIMPLE_MTLX)

    ok = subprocess.run([script, "inspect", str(asset), "--json"], capture_output=True, text=True,
                        cwd=tmp_path, timeout=300, check=False)
    assert ok.returncode == 0, ok.stderr
    report = json.loads(ok.stdout)
    assert report["asset"] == str(asset)
    assert [m["material"] for m in report["materials"]] == ["Red"]

    # A non-zero return from main() must reach the shell.
    refused = subprocess.run([script, str(tmp_path / "nope.mtlx")], capture_output=True, text=True, cwd=tmp_path,
                             timeout=300, check=False)
    assert refused.returncode == 2
    assert "nope.mtlx" in refused.stderr and "Traceback" not in refused.stderr


def test_allow_missing_textures_uses_the_declared_default(capsys):
    path = shared_path("materialx", "resources", "Materials", "Examples", "StandardSurface",
                       "standard_surface_brass_tiled.mtlx")
    assert main(["inspect", str(path)]) == 2  # brass_color.jpg is missing: a clear error by default
    assert "--allow-missing-textures" in capsys.readouterr().err
    assert main(["inspect", str(path), "--allow-missing-textures", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    notes = " ".join(report["materials"][0]["approximations"])
    assert "brass_color.jpg" in notes and "default" in notes
