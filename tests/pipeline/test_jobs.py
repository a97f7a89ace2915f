"""Per-material jobs: the error budget, training only what the scene needs, parallel runners.

Trainings are tiny (20 steps of 256 samples, a couple of seconds each on a 2-core
CPU): these tests check the decisions (which decoder, which materials train, which
share, which grid), not the fidelity. The pool and Ray tests check that the same job
function ran in other processes, one torch thread each.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

import mtlx2neural as m2n
from mtlx2neural.cli import main
from mtlx2neural.pipeline.budget import choose_decoder
from mtlx2neural.pipeline.convert import convert_asset
from mtlx2neural.pipeline.options import ConvertOptions
from mtlx2neural.pipeline.workers import parse_workers
from mtlx2neural.train.config import preset

TINY = preset("fast", iterations=20, batch=256)
CLI_TINY = ["--iterations", "20", "--batch", "256", "--device", "cpu"]

from materials import TEXTURED_MTLX, TWO_MTLX  # noqa: E402  (shared documents)


def write_png(path: Path, size: int) -> None:
    import OpenImageIO as oiio

    g = np.random.default_rng(0)
    img = (g.random((size, size, 3)) * 255).astype(np.uint8)
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(size, size, 3, "uint8"))
    out.write_image(img)
    out.close()


def textured_asset(folder: Path, size: int = 8) -> Path:
    write_png(folder / "albedo.png", size)
    asset = folder / "tex.mtlx"
    asset.write_text(TEXTURED_MTLX)
    return asset


def make_stage(path: Path, materials: dict[str, tuple], bound: list[str]) -> None:
    """A USD stage with one Mesh per bound material and UsdShade standard_surface networks.

    ``materials``: Material name -> base colour. Every network has the same prim names
    (``<Material>/SR``), so equal colours mean equal graphs.
    """
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Xform.Define(stage, "/World")
    UsdGeom.Scope.Define(stage, "/World/Looks")
    mats = {}
    for name, color in materials.items():
        mat = UsdShade.Material.Define(stage, f"/World/Looks/{name}")
        shader = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/SR")
        shader.CreateIdAttr("ND_standard_surface_surfaceshader")
        shader.CreateInput("base_color", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*color))
        mat.CreateOutput("mtlx:surface", Sdf.ValueTypeNames.Token).ConnectToSource(
            shader.CreateOutput("out", Sdf.ValueTypeNames.Token))
        mats[name] = mat
    for name in bound:
        mesh = UsdGeom.Mesh.Define(stage, f"/World/Geo_{name}")
        mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
        mesh.CreateFaceVertexCountsAttr([3])
        mesh.CreateFaceVertexIndicesAttr([0, 1, 2])
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mats[name])
    stage.GetRootLayer().Save()


@pytest.fixture
def three_stage(tmp_path) -> Path:
    """Three materials: A and B identical by graph (both bound), C unbound."""
    asset = tmp_path / "three.usda"
    make_stage(asset, {"A": (0.8, 0.1, 0.1), "B": (0.8, 0.1, 0.1), "C": (0.1, 0.8, 0.1)}, bound=["A", "B"])
    return asset


def count_trainings(monkeypatch) -> list:
    """Patch Trainer.run to record each training (in this process) and return the record."""
    from mtlx2neural.train.trainer import Trainer

    runs, original = [], Trainer.run

    def run(self, progress=True, listener=None, probe=None):
        runs.append(self.cfg.decoder)
        return original(self, progress, listener, probe)

    monkeypatch.setattr(Trainer, "run", run)
    return runs


def count_fits(monkeypatch) -> list:
    """Patch the jobs' analytic fit (the UsdPreviewSurface baseline) to record each fit's step count."""
    from mtlx2neural.pipeline import material_training

    fits, original = [], material_training.fit_analytic

    def fit(*args, **kwargs):
        fits.append(kwargs.get("iterations"))
        return original(*args, **kwargs)

    monkeypatch.setattr(material_training, "fit_analytic", fit)
    return fits


def preview_flip_in_layer(usda: Path, prim: str) -> float:
    from pxr import Usd

    stage = Usd.Stage.Open(str(usda))  # held: a prim of a collected stage has expired
    return stage.GetPrimAtPath(prim).GetAttribute("neural:metrics:previewFlip").Get()


# ----------------------------------------------------------------------------- the error budget


def test_choose_decoder_stops_at_the_first_size_meeting_the_budget():
    errors = {"2x16": 0.30, "2x32": 0.12, "3x64": 0.05}
    tried = []

    def measure(d):
        tried.append(d)
        return errors[d]

    assert choose_decoder(measure, 0.5) == ("2x16", {"2x16": 0.30})
    tried.clear()
    assert choose_decoder(measure, 0.15) == ("2x32", {"2x16": 0.30, "2x32": 0.12})
    assert tried == ["2x16", "2x32"]  # 3x64 never trained
    assert choose_decoder(measure, 0.05) == ("3x64", errors)  # the budget is inclusive


def test_choose_decoder_keeps_the_best_when_nothing_meets_the_budget():
    decoder, flips = choose_decoder({"2x16": 0.30, "2x32": 0.12, "3x64": 0.20}.get, 0.01)
    assert decoder == "2x32" and len(flips) == 3 and not flips[decoder] <= 0.01
    decoder, flips = choose_decoder({"2x16": 0.3, "2x32": 0.3, "3x64": 0.3}.get, 0.01)
    assert decoder == "2x16"  # a tie: the smaller
    decoder, flips = choose_decoder(lambda d: math.nan if d != "2x32" else 0.4, 0.1)
    assert decoder == "2x32" and math.isnan(flips["3x64"])  # NaN never meets nor wins
    decoder, _ = choose_decoder(lambda d: math.nan, 0.1)
    assert decoder == "3x64"


@pytest.mark.slow
def test_budget_missed_trains_every_size_and_says_so(tmp_path, capsys, monkeypatch):
    asset = tmp_path / "two.mtlx"
    asset.write_text(TWO_MTLX)
    runs, fits = count_trainings(monkeypatch), count_fits(monkeypatch)
    code = main([str(asset), "--material", "Red", "--max-error", "1e-9", "--quiet", "--workers", "1", *CLI_TINY])
    out = capsys.readouterr().out
    assert code == 0
    assert runs == ["2x16", "2x32", "3x64"]
    # the preview baseline does not depend on the decoder: fitted once, for the fast preset's 100 steps
    assert fits == [100]
    assert "budget HDR FLIP <= 1e-09: NOT met" in out
    assert "warning: HDR FLIP budget 1e-09 not met: even the largest decoder, 3x64" in out
    folder = tmp_path / "two_neural" / "Red"
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["budget_met"] is False and summary["budget"]["met"] is False
    assert list(summary["budget"]["flip_by_decoder"]) == ["2x16", "2x32", "3x64"]
    kept = summary["decoder"]
    assert summary["flip_mean"] == min(summary["budget"]["flip_by_decoder"].values())
    assert summary["config"]["decoder"] == kept and any("not met" in n for n in summary["notes"])
    assert not (folder / "budget").exists()  # the other sizes' files are gone; the kept one moved up
    assert (folder / "analytic_baseline.pt").is_file() and math.isfinite(summary["preview_flip"])
    assert summary["preview_flip"] > 0  # float32 in the layer against the summary's 4 decimals:
    assert preview_flip_in_layer(tmp_path / "two_neural.usda", "/Materials/Red") == pytest.approx(
        summary["preview_flip"], abs=1e-6)
    assert m2n.load_neural(tmp_path / "two_neural.usda", "Red").usd_info["material"] == "/Materials/Red"
    arch = json.loads((folder / "neural" / "weights.json").read_text())["architecture"]
    layers, width = map(int, kept.split("x"))
    assert arch["decoder_hidden"] == [width] * layers  # the kept size is what was exported

    runs.clear()  # unchanged: the whole budgeted result is cached, the preview baseline too
    fits.clear()
    assert main([str(asset), "--material", "Red", "--max-error", "1e-9", "--quiet", "--workers", "1",
                 *CLI_TINY]) == 0
    assert runs == [] and fits == [] and "reused" in capsys.readouterr().out
    assert preview_flip_in_layer(tmp_path / "two_neural.usda", "/Materials/Red") == pytest.approx(
        summary["preview_flip"], abs=1e-6)


def test_budget_met_by_the_smallest_decoder(tmp_path, monkeypatch):
    asset = tmp_path / "two.mtlx"
    asset.write_text(TWO_MTLX)
    runs = count_trainings(monkeypatch)
    s = convert_asset(asset, ConvertOptions(train=TINY, material="Red", progress=False, device="cpu",
                                          max_error=10.0, workers=1))[0]
    assert runs == ["2x16"] and s.decoder == "2x16" and s.budget_met is True
    assert s.budget["flip_by_decoder"] == {"2x16": s.flip_mean}
    assert not [w for w in s.warnings if "budget" in w]  # met: nothing to say about it (a 30-step model
    # is still warned about its energy, which the energy check's own tests cover)


@pytest.mark.slow
def test_preview_iterations_zero_fits_no_preview_and_drops_an_old_one(tmp_path, monkeypatch):
    """``preview_iterations = 0`` fits no analytic baseline (plain and error-budget runs) and removes the
    baseline of an earlier run, which would otherwise be exported as this run's fallback."""
    import dataclasses

    asset = tmp_path / "two.mtlx"
    asset.write_text(TWO_MTLX)
    fits = count_fits(monkeypatch)
    folder, usda = tmp_path / "two_neural" / "Red", tmp_path / "two_neural.usda"
    convert_asset(asset, ConvertOptions(train=TINY, material="Red", progress=False, device="cpu", workers=1))
    assert fits == [100] and (folder / "analytic_baseline.pt").is_file()
    off = dataclasses.replace(TINY, preview_iterations=0)
    for max_error in (None, 10.0):  # train_material, then train_within_budget
        fits.clear()
        s = convert_asset(asset, ConvertOptions(train=off, material="Red", progress=False, device="cpu", workers=1,
                                                max_error=max_error))[0]
        assert fits == [] and s.preview_flip is None and not (folder / "analytic_baseline.pt").exists()
        assert preview_flip_in_layer(usda, "/Materials/Red") is None
        assert any("preview_iterations = 0" in n for n in s.export_notes)


def test_preview_iterations_per_preset():
    from mtlx2neural.errors import InputError
    from mtlx2neural.train.config import TrainConfig, validate_config

    assert TrainConfig().preview_iterations == 200 and preset("fast").preview_iterations == 100
    assert preset("standard").preview_iterations == 200 and preset("balanced").preview_iterations == 200
    validate_config(preset("fast", preview_iterations=0))  # 0: no fallback, allowed
    with pytest.raises(InputError, match="--preview-iterations"):
        validate_config(preset("fast", preview_iterations=-1))


def test_decoder_and_max_error_conflict(tmp_path, capsys):
    asset = tmp_path / "two.mtlx"
    asset.write_text(TWO_MTLX)
    code = main([str(asset), "--decoder", "2x16", "--max-error", "0.1", "--quiet"])
    out, err = capsys.readouterr()
    assert code == 2 and out == "" and "Traceback" not in err
    assert "--decoder 2x16 and --max-error 0.1 conflict" in err and "Give one of them" in err
    assert not (tmp_path / "two_neural").exists()
    for bad in (["--max-error", "-1"], ["--max-error", "abc"], ["--max-texels", "-3"], ["--workers", "0"],
                ["--workers", "dask"]):
        with pytest.raises(SystemExit) as e:
            main([str(asset), *bad])
        assert e.value.code == 2
    assert "ray://HOST:PORT" in capsys.readouterr().err


def test_parse_workers():
    assert parse_workers(None) is None and parse_workers("auto") is None
    assert parse_workers("3") == 3 and parse_workers(2) == 2
    assert parse_workers("ray") == "ray" and parse_workers("ray://head:10001") == "ray://head:10001"
    for bad in ("0", "ray://", "x"):
        with pytest.raises(ValueError):
            parse_workers(bad)


# ----------------------------------------------------------------------------- only what the scene needs


def test_identical_materials_train_once_and_unbound_ones_are_skipped(three_stage, capsys, monkeypatch):
    runs = count_trainings(monkeypatch)
    code = main([str(three_stage), "--workers", "1", *CLI_TINY])
    out = capsys.readouterr().out
    assert code == 0
    assert len(runs) == 1  # exactly one model trained
    assert ("/World/Looks/B: identical to /World/Looks/A (same compiled graph, textures and settings; "
            "content hash") in out
    assert "/World/Looks/C: skipped (not bound" in out
    out_dir = three_stage.parent / "three_neural"
    a = json.loads((out_dir / "World.Looks.A" / "summary.json").read_text())
    b = json.loads((out_dir / "World.Looks.B" / "summary.json").read_text())
    assert a["shared_with"] is None and b["shared_with"] == "/World/Looks/A"
    assert b["material"] == "/World/Looks/B" and b["content_hash"] == a["content_hash"]
    assert b["source_hash"] != a["source_hash"]  # the cache key names the material
    assert b["steps"] == a["steps"] and b["flip_mean"] == a["flip_mean"]
    assert b["preview_flip"] == a["preview_flip"] and (out_dir / "World.Looks.B" / "analytic_baseline.pt").is_file()
    assert not (out_dir / "World.Looks.C").exists()
    usda = three_stage.parent / "three_neural.usda"
    wi = torch.tensor([[0.0, 0.6, 0.8], [0.3, 0.1, 0.95]])
    wo = torch.tensor([[0.0, -0.6, 0.8], [-0.5, 0.2, 0.84]])
    wi, wo = torch.nn.functional.normalize(wi, dim=-1), torch.nn.functional.normalize(wo, dim=-1)
    with torch.no_grad():  # B's exported files are its own copies of A's
        torch.testing.assert_close(m2n.load_neural(usda, "B").eval(wi, wo), m2n.load_neural(usda, "A").eval(wi, wo))
    assert (out_dir / "World.Looks.B" / "neural" / "weights.bin").read_bytes() == \
        (out_dir / "World.Looks.A" / "neural" / "weights.bin").read_bytes()

    assert preview_flip_in_layer(usda, "/World/Looks/B") == pytest.approx(b["preview_flip"], abs=1e-6)

    runs.clear()  # again: A is reused, B shares it again, nothing trains
    fits = count_fits(monkeypatch)
    assert main([str(three_stage), "--workers", "1", "--quiet", *CLI_TINY]) == 0
    out = capsys.readouterr().out
    assert runs == [] and fits == [] and "/World/Looks/A: reused" in out and "/World/Looks/B: identical to /World/Looks/A" in out


def test_materials_differing_in_a_value_both_train(tmp_path, monkeypatch):
    asset = tmp_path / "two.usda"
    make_stage(asset, {"A": (0.8, 0.1, 0.1), "B": (0.8, 0.1, 0.2)}, bound=["A", "B"])
    from mtlx2neural.pipeline.plan import plan_materials
    from mtlx2neural.scene import load_asset

    plans = plan_materials(load_asset(asset).materials, TINY)
    assert [p.shared_with for p in plans] == [None, None] and plans[0].content != plans[1].content


def test_inspect_shows_the_decisions(three_stage, tmp_path, capsys):
    code = main(["inspect", str(three_stage), "--json"])
    report = json.loads(capsys.readouterr().out)
    assert code == 0
    a, b = report["materials"]
    assert a["latent"]["kind"] == "uniform" and a["latent"]["grid"] == [1, 1] and a["identical_to"] is None
    assert b["identical_to"] == "/World/Looks/A" and b["content_hash"] == a["content_hash"]
    assert main(["inspect", str(three_stage)]) == 0
    text = capsys.readouterr().out
    assert "latent grid: 1x1 (spatially uniform" in text
    assert f"source hash: {a['source_hash'][:12]}  (content {a['content_hash'][:12]})" in text
    assert "identical to /World/Looks/A: trained once" in text

    tex = textured_asset(tmp_path, size=8)
    assert main(["inspect", str(tex), "--max-texels", "4"]) == 0
    text = capsys.readouterr().out
    assert "latent grid: 4x4, capped (textures 8x8" in text and "warning: latent grid capped to 4x4" in text
    assert main(["inspect", str(tex), "--json"]) == 0
    native = json.loads(capsys.readouterr().out)["materials"][0]["latent"]
    assert native["kind"] == "native" and native["grid"] == [8, 8] and native["max_texels"] == 256


def test_constant_parameters_never_enter_the_encoder(tmp_path):
    """One texture-driven parameter (the diffuse colour, color3): the stack and the encoder input are 3 wide."""
    from mtlx2neural.graph import compile_material
    from mtlx2neural.reference import ReferenceMaterial
    from mtlx2neural.scene import find_material
    from mtlx2neural.textures.parameter_stack import build_parameter_stack
    from mtlx2neural.train.trainer import Trainer

    src = find_material(textured_asset(tmp_path), "Tex")
    compiled = compile_material(src.document, src.material)
    stack = build_parameter_stack(compiled, resolution=(4, 4))
    assert [(c.name.rsplit(".", 1)[-1], c.width) for c in stack.channels] == [("color", 3)]
    assert stack.levels[0].shape[0] == 3
    assert len(stack.constants) > 10  # everything else stays a constant
    trainer = Trainer(ReferenceMaterial(compiled), stack, TINY, tmp_path / "t")
    first = next(m for m in trainer.model.encoder.modules() if isinstance(m, torch.nn.Linear))
    assert first.in_features == 3


@pytest.mark.slow
def test_max_texels_caps_the_grid_and_warns(tmp_path, capsys):
    tex = textured_asset(tmp_path, size=8)
    assert main([str(tex), "--max-texels", "4", "--quiet", *CLI_TINY]) == 0
    out = capsys.readouterr().out
    assert "warning: latent grid capped to 4x4 texels (max 4 per side) below the textures' 8x8" in out
    summary = json.loads((tmp_path / "tex_neural" / "Tex" / "summary.json").read_text())
    assert summary["resolution"] == [4, 4] and summary["varying_channels"] == 3
    assert any("capped to 4x4" in n for n in summary["notes"]) and summary["warnings"]
    # the conversion's options are recorded from the same dataclass the flags come from
    assert summary["options"]["preset"] == "fast" and summary["options"]["device"] == "cpu"
    assert summary["options"]["progress"] is False and "train" not in summary["options"]
    assert summary["config"]["max_resolution"] == 4  # --max-texels lands in the training settings


# ----------------------------------------------------------------------------- parallel runners


@pytest.mark.slow
def test_process_pool_trains_two_materials_in_two_workers(tmp_path, capfd):
    asset = tmp_path / "two.mtlx"
    asset.write_text(TWO_MTLX)
    env = os.environ.get("OMP_NUM_THREADS")
    summaries = convert_asset(asset, ConvertOptions(train=TINY, device="cpu", workers=2))
    assert os.environ.get("OMP_NUM_THREADS") == env  # set for the workers only
    out, err = capfd.readouterr()  # file descriptors: the workers' output too
    assert [s.material for s in summaries] == ["Red", "Blue"]  # scene order, whatever finished first
    assert [s.cached for s in summaries] == [False, False]
    workers = {s.worker for s in summaries}
    assert len(workers) == 2 and not any(w.endswith(f":{os.getpid()}") for w in workers)
    assert all(s.threads == max(1, len(os.sched_getaffinity(0)) // 2) for s in summaries)
    assert "[1/2]" in out and "[2/2]" in out
    # One bar per material, drawn by the parent from the workers' progress messages (phase, loss).
    assert "Red:" in err and "Blue:" in err and "loss=" in err
    for s in summaries:
        assert m2n.load_neural(s.usd, s.material).usd_info["material"] == "/Materials/" + s.material


@pytest.mark.slow
def test_ray_local_cluster_runs_the_same_jobs(tmp_path, capsys):
    ray = pytest.importorskip("ray", reason="the optional 'ray' extra is not installed")
    asset = tmp_path / "three.usda"
    make_stage(asset, {"A": (0.8, 0.1, 0.1), "B": (0.1, 0.8, 0.1), "C": (0.1, 0.1, 0.8)}, bound=["A", "B", "C"])
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        summaries = convert_asset(asset, ConvertOptions(train=TINY, device="cpu", workers="ray"))
        assert m2n.load_neural(tmp_path / "three_neural.usda", "C").usd_info["material"] == "/World/Looks/C"
        # A ray:// address ships the files back with the result (this cluster stands in for a remote one:
        # an initialised Ray is used as it is).
        folder = tmp_path / "three_neural" / "World.Looks.A"
        shutil.rmtree(folder)
        shipped = convert_asset(asset, ConvertOptions(train=TINY, material="A", device="cpu",
                                                           workers="ray://remote.invalid:10001"))
    finally:
        ray.shutdown()
    assert not shipped[0].cached and shipped[0].flip_mean == summaries[0].flip_mean
    assert {"checkpoint.pt", "summary.json", "training_curves.csv", "view0_flip.png"} <= \
        {p.name for p in folder.iterdir()}
    out = capsys.readouterr().out
    assert [s.material for s in summaries] == ["/World/Looks/A", "/World/Looks/B", "/World/Looks/C"]
    assert all(not s.cached and s.steps == 20 and s.threads == 1 for s in summaries)
    assert not any(s.worker.endswith(f":{os.getpid()}") for s in summaries)
    assert "[3/3]" in out


@pytest.mark.slow  # trains and renders: ~1 min of CPU
def test_a_job_carries_the_stage_and_trains_on_the_rasterised_mesh(tmp_path):
    """A position-driven material: the job rebuilds its source with the stage file, and training reads
    the bound quad's geometry (the summary says so)."""
    pytest.importorskip("pxr", reason="usd-core is needed for a USD stage")
    # Local: the helpers this test alone uses.
    from materials import usd_quad_reading_position

    from mtlx2neural.pipeline.jobs import make_job
    from mtlx2neural.pipeline.material_training import train_material
    from mtlx2neural.pipeline.plan import plan_materials
    from mtlx2neural.scene import load_asset

    path = tmp_path / "quad.usda"
    path.write_text(usd_quad_reading_position("object"))
    cfg = preset("fast", iterations=2, batch=64, preview_iterations=0)
    (plan,) = plan_materials(load_asset(str(path)).materials, cfg, asset=str(path))
    job = make_job(plan, tmp_path / "M", cfg)
    src = job.source()
    assert src.stage_file == str(path) and src.bound_prims == ["/World/Quad"]
    _, summary = train_material(src, cfg, tmp_path / "M", "cpu", False, False, False, plan.digest,
                                resolution=(4, 4), preview=False)
    assert any("rasterised from the bound meshes' UV layout (/World/Quad)" in n for n in summary.notes)


def test_the_record_carries_the_energy_check_and_warns_when_dark(tmp_path):
    """A 30-step model of a red plastic is far darker than its reference: the record holds the energy
    check (one ratio per MIP level of a uniform material: one) and a warning naming it."""
    asset = tmp_path / "two.mtlx"
    asset.write_text(TWO_MTLX)
    (s,) = convert_asset(asset, ConvertOptions(train=TINY, material="Red", progress=False, device="cpu"))
    assert len(s.energy["by_level"]) == 1 and s.energy["min_ratio"] == s.energy["by_level"][0]
    assert 0.0 <= s.energy["min_ratio"] < 0.9 and 0.0 < s.energy["reference_by_level"][0] < 1.0
    (warning,) = [w for w in s.warnings if "energy check" in w]
    assert f"{s.energy['min_ratio']:.0%}" in warning and warning in s.notes
