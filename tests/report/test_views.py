"""``mtlx2neural render --model neural`` from the exported layer and its files (what ships), the
choice between that layer and the training checkpoint, stage snapshots, and a clear exit 2
naming the file for every missing or corrupt exported file.

No training: a seeded random NeuralMaterial is exported with :func:`export_asset` (about a second),
so these tests check which model renders and what the errors say, not fidelity. Renders are 12x12
at 2 spp on a plane (about a second each on 2 shared cores).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import torch
from cli_helpers import assert_clean_input_error, run_cli
from conftest import SIMPLE_MTLX, write_float_image
from materials import usd_painted_ball
from neural_models import randomise_latents
from pxr import Usd

from mtlx2neural.errors import InputError
from mtlx2neural.export import export_asset
from mtlx2neural.export.load import load_neural
from mtlx2neural.material_record import MaterialRecord, write_record
from mtlx2neural.model.neural_material import NeuralMaterial
from mtlx2neural.pipeline.layout import (
    SNAPSHOT_NAME,
    material_folder,
    prepare_folder,
    resolve_output,
)
from mtlx2neural.report.views import render_asset
from mtlx2neural.scene.snapshot import flatten, write_snapshot

COMMON = ("--res", "12", "--spp", "2", "--geometry", "plane")
KW = {"res": 12, "spp": 2, "geometry": "plane"}


def random_model(seed: int) -> NeuralMaterial:
    """A textured (5x3 latent grid, 6 channels: two latent EXRs) model with random latents."""
    torch.manual_seed(seed)
    m = NeuralMaterial((3, 5), in_dim=2, latent_dim=6, frames=2, decoder="2x16")
    randomise_latents(m)
    return m.train(False)


def summary(name: str) -> MaterialRecord:
    return MaterialRecord(name, name, "", "0" * 64, flip_mean=0.125, steps=30, device="cpu",
                          device_name="cpu (test)", train_seconds=1.5)


def save_checkpoint(model: NeuralMaterial, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"model": model.state_dict(), "config": {"analytic_cosine": True}}, path)
    return path


def pixels(path) -> np.ndarray:
    import OpenImageIO as oiio

    return oiio.ImageBuf(str(path)).get_pixels(oiio.FLOAT)


@pytest.fixture
def exported(tmp_path):
    """red.mtlx, exported as ``mtlx2neural red.mtlx`` lays it out (red_neural.usda, red_neural/Red/neural/)."""
    asset = tmp_path / "red.mtlx"
    asset.write_text(SIMPLE_MTLX)
    layout = resolve_output(asset)
    folder = layout.folder / material_folder("Red")
    layer, _ = export_asset(asset, [(random_model(0), summary("Red"), folder)], layout.folder, "fast")
    return {"asset": asset, "layer": layer, "folder": folder, "files": folder / "neural"}


def test_the_neural_layer_renders_its_exported_files_not_a_checkpoint(exported, tmp_path, capsys):
    out = tmp_path / "layer.exr"
    code, stdout, err = run_cli(capsys, "render", exported["layer"], "--model", "neural", "-o", out, *COMMON)
    assert code == 0, err
    assert f"from the layer {exported['layer']}" in stdout
    s = render_asset(exported["layer"], tmp_path / "api.exr", model="neural", **KW)
    assert (s["neural_source"], s["neural_path"], s["checkpoint"], s["material"]) == (
        "layer", str(exported["layer"]), None, "Red")
    np.testing.assert_array_equal(pixels(out), pixels(tmp_path / "api.exr"))  # same seed, same model

    # The layer holds the model's FP16 values: a checkpoint of another model is a different image,
    # a checkpoint of the loaded model the same one (equal to float32 rounding: tolerance 1e-5).
    other = save_checkpoint(random_model(1), tmp_path / "other" / "checkpoint.pt")
    s = render_asset(exported["layer"], tmp_path / "other.exr", model="neural", checkpoint=other, **KW)
    assert (s["neural_source"], s["checkpoint"]) == ("checkpoint", str(other))
    assert np.abs(pixels(tmp_path / "other.exr") - pixels(out)).max() > 1e-2
    loaded = load_neural(exported["layer"], "Red")
    same = save_checkpoint(loaded, tmp_path / "same" / "checkpoint.pt")
    render_asset(exported["layer"], tmp_path / "same.exr", model="neural", checkpoint=same, **KW)
    np.testing.assert_allclose(pixels(tmp_path / "same.exr"), pixels(out), rtol=1e-5, atol=1e-6)

    # --model reference on the layer renders the original material of the input it records.
    s = render_asset(exported["layer"], tmp_path / "ref.exr", **KW)
    direct = render_asset(exported["asset"], tmp_path / "ref_direct.exr", **KW)
    assert (s["material"], s["neural_source"]) == ("Red", None)
    np.testing.assert_array_equal(pixels(tmp_path / "ref.exr"), pixels(tmp_path / "ref_direct.exr"))
    assert direct["mean"] > 0


def test_env_mode_prefiltered_shades_the_environment_head_of_the_exported_layer(tmp_path, capsys):
    """A model with an environment head, exported and read back: ``--env-mode prefiltered`` shades the sky
    from its learned lobes (the same image as render.prefiltered on the loaded model), the reference stays
    sampled (the same image in both modes), and an unknown mode is an InputError."""
    from mtlx2neural.render.geometry import Camera, Plane
    from mtlx2neural.render.lighting import EnvironmentMap
    from mtlx2neural.render.prefiltered import PrefilteredEnvironment
    from mtlx2neural.render.renderer import render_scene

    asset = tmp_path / "red.mtlx"
    asset.write_text(SIMPLE_MTLX)
    layout = resolve_output(asset)
    torch.manual_seed(4)
    model = NeuralMaterial((3, 5), in_dim=2, latent_dim=6, frames=2, decoder="2x16", environment_head=True).train(False)
    layer, _ = export_asset(asset, [(model, summary("Red"), layout.folder / material_folder("Red"))], layout.folder, "fast")
    loaded = load_neural(layer, "Red")
    assert loaded.has_environment_head  # the head travels through weights.bin / weights.json
    out = tmp_path / "prefiltered.exr"
    code, _, err = run_cli(capsys, "render", layer, "--model", "neural", "--env-mode", "prefiltered", "-o", out, *COMMON)
    assert code == 0, err
    direct = render_scene(loaded, Plane(), Camera(30.0, 20.0, 4.0, 30.0), [PrefilteredEnvironment(EnvironmentMap.sky())],
                          12, 2, tuple(loaded.latents.levels[0].shape[-2:]), 0, sampler=loaded)
    np.testing.assert_allclose(pixels(out), direct, rtol=1e-6, atol=1e-7)
    sampled = render_asset(layer, tmp_path / "sampled.exr", model="neural", **KW)
    assert sampled["env_mode"] == "sampled" and np.abs(pixels(tmp_path / "sampled.exr") - pixels(out)).max() > 1e-3
    for mode in ("sampled", "prefiltered"):
        render_asset(layer, tmp_path / f"ref_{mode}.exr", env_mode=mode, **KW)
    np.testing.assert_array_equal(pixels(tmp_path / "ref_sampled.exr"), pixels(tmp_path / "ref_prefiltered.exr"))
    with pytest.raises(InputError, match="--env-mode"):
        render_asset(layer, tmp_path / "x.exr", env_mode="split", **KW)


def test_the_original_asset_prefers_the_layer_beside_it_then_the_checkpoint(exported, tmp_path):
    ck = save_checkpoint(random_model(1), exported["folder"] / "checkpoint.pt")  # where training writes it
    s = render_asset(exported["asset"], tmp_path / "a.exr", model="neural", **KW)
    assert (s["neural_source"], s["neural_path"]) == ("layer", str(exported["layer"]))
    from_layer = render_asset(exported["layer"], tmp_path / "b.exr", model="neural", **KW)
    assert from_layer["neural_source"] == "layer"
    np.testing.assert_array_equal(pixels(tmp_path / "a.exr"), pixels(tmp_path / "b.exr"))

    # A layer written for another input does not count: the checkpoint renders.
    record = exported["layer"].read_text()
    exported["layer"].write_text(record.replace('string source = "./red.mtlx"', 'string source = "./blue.mtlx"'))
    s = render_asset(exported["asset"], tmp_path / "c.exr", model="neural", **KW)
    assert (s["neural_source"], s["checkpoint"]) == ("checkpoint", str(ck))
    exported["layer"].unlink()  # no layer: the checkpoint, as before layers were read back
    s = render_asset(exported["asset"], tmp_path / "d.exr", model="neural", **KW)
    assert (s["neural_source"], s["checkpoint"]) == ("checkpoint", str(ck))
    np.testing.assert_array_equal(pixels(tmp_path / "c.exr"), pixels(tmp_path / "d.exr"))
    assert np.abs(pixels(tmp_path / "d.exr") - pixels(tmp_path / "a.exr")).max() > 1e-2


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[:-8])  # the last (1x1) MIP level's tile loses its data


def _halve(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 4])  # inside the header


def _three_channels(path: Path) -> None:
    path.unlink()
    write_float_image(path, np.full((3, 5, 3), 0.5, np.float32))


def _garbage(path: Path) -> None:
    path.write_bytes(b"\x76\x2f\x31\x01" + bytes(range(256)) * 4)  # the EXR magic number, then noise


def _grow(path: Path) -> None:
    path.write_bytes(path.read_bytes() + b"\0" * 64)


def _bad_json(path: Path) -> None:
    path.write_text(path.read_text()[:-40])


def _no_architecture(path: Path) -> None:
    manifest = json.loads(path.read_text())
    del manifest["architecture"]
    path.write_text(json.dumps(manifest))


CORRUPTIONS = {
    "missing latent EXR": ("latents_1.exr", Path.unlink, "does not exist"),
    "truncated latent EXR": ("latents_0.exr", _truncate, "cannot be decoded"),
    "latent EXR cut in its header": ("latents_0.exr", _halve, "cannot be read"),
    "corrupt latent EXR": ("latents_0.exr", _garbage, "cannot be read"),
    "three-channel latent EXR": ("latents_1.exr", _three_channels, "has 3 channel(s)"),
    "missing weights.bin": ("weights.bin", Path.unlink, "does not exist"),
    "weights.bin of the wrong size": ("weights.bin", _grow, "size or sha256 differs"),
    "corrupt weights.json": ("weights.json", _bad_json, "cannot read the weights manifest"),
    "weights.json without architecture": ("weights.json", _no_architecture, "malformed weights manifest"),
    "missing weights.json": ("weights.json", Path.unlink, "does not exist"),
}


@pytest.mark.parametrize("case", list(CORRUPTIONS))
def test_a_missing_or_corrupt_exported_file_exits_2_naming_it(exported, tmp_path, capsys, case):
    name, corrupt, what = CORRUPTIONS[case]
    target = exported["files"] / name
    corrupt(target)
    out = tmp_path / "x.exr"
    for asset in (exported["layer"], exported["asset"]):  # the layer, and the asset it lies beside
        code, stdout, err = run_cli(capsys, "render", asset, "--model", "neural", "-o", out, *COMMON)
        assert_clean_input_error(code, stdout, err, os.path.realpath(target), what)
        assert not out.exists() and not out.with_suffix(".png").exists()


def test_a_stage_snapshot_finds_its_conversions_layer_and_checkpoint(tmp_path, capsys):
    """An in-memory stage's conversion writes OUT/stage-snapshot.usda, OUT/<material>/ and OUT.usda
    (the steps of pipeline.convert, without training): ``render OUT/stage-snapshot.usda --model
    neural`` reads OUT.usda, or without it OUT/<material>/checkpoint.pt."""
    stage = Usd.Stage.CreateInMemory()
    stage.GetRootLayer().ImportFromString(usd_painted_ball("float inputs:base = 0.8"))
    layout = resolve_output(None, tmp_path / "out")
    snapshot = layout.folder / SNAPSHOT_NAME
    prepare_folder(layout, snapshot, "test")
    write_snapshot(flatten(stage), snapshot)
    name = "/World/Looks/Paint"
    folder = layout.folder / material_folder(name)
    layer, _ = export_asset(snapshot, [(random_model(0), summary(name), folder)], layout.folder, "fast",
                            usda=layout.layer)
    out = tmp_path / "r.exr"
    code, stdout, err = run_cli(capsys, "render", snapshot, "--model", "neural", "-o", out, *COMMON)
    assert code == 0, err
    assert f"from the layer {layer}" in stdout and pixels(out).shape == (12, 12, 3)
    layer.unlink()
    ck = save_checkpoint(random_model(0), folder / "checkpoint.pt")
    s = render_asset(snapshot, out, model="neural", **KW)
    assert (s["neural_source"], s["checkpoint"], s["material"]) == ("checkpoint", str(ck), name)
    ck.unlink()  # neither: exit 2 naming the checkpoint it looked for
    code, stdout, err = run_cli(capsys, "render", snapshot, "--model", "neural", "-o", out, *COMMON)
    assert_clean_input_error(code, stdout, err, str(ck))


def test_the_reference_renders_at_the_conversions_instant_or_the_given_one(tmp_path, capsys):
    """A material whose base colour is the ``time`` node: render reads the instant the conversion baked it
    at from its record (summary.json, as a conversion writes it), and --frame/--fps override it; a record
    of another version is an error naming it, not a silent frame 1."""
    # Local: the shared MaterialX snippets, for this test only.
    from materials import FOOTER, HEADER, standard_surface

    asset = tmp_path / "clock.mtlx"
    asset.write_text(HEADER + '  <time name="t" type="float" />\n  <convert name="tc" type="color3">\n'
                     '    <input name="in" type="float" nodename="t" />\n  </convert>\n'
                     + standard_surface("Clock", "SR", base=1.0, base_color={"node": "tc"}) + FOOTER)
    default = render_asset(asset, tmp_path / "default.exr", **KW)["mean"]  # frame 1 at 24 fps: t = 1/24
    folder = resolve_output(asset).folder / material_folder("Clock")
    folder.mkdir(parents=True)
    record = MaterialRecord("Clock", "Clock", str(asset), "",
                            application={"frame": 12.0, "fps": 24.0, "time": 0.5, "nodes": ["time"]})
    write_record(folder, record)
    converted = render_asset(asset, tmp_path / "converted.exr", **KW)["mean"]  # t = 0.5
    given = render_asset(asset, tmp_path / "given.exr", frame=1.0, **KW)["mean"]  # --frame 1 at the 24 fps
    # Same seed and light samples: the diffuse part scales 12x with the base colour, the specular part does
    # not (3.6x in all, measured); rendering the same instant twice is bit-identical.
    assert converted > 2.0 * default and given == default
    code, _, err = run_cli(capsys, "render", asset, "-o", tmp_path / "cli.exr", "--frame", "24", "--fps", "48", *COMMON)
    assert code == 0, err  # t = 24 / 48 = 0.5, as the conversion's: the same image
    assert np.allclose(pixels(tmp_path / "cli.exr"), pixels(tmp_path / "converted.exr"), rtol=1e-6, atol=0)
