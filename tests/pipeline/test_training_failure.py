"""Training-failure isolation: a material whose training raises (here a forced non-finite loss) is
skipped like one that cannot be compiled: the others train and export, the CLI names it with the
reason, the layer's record and the library result list it, exit 3; nothing else converted: exit 2;
``--strict``: exit 2 and nothing written.

Training is forced to fail by monkeypatching ``train_material`` in this process (``--workers 1``);
the conversions train nothing (``--iterations 0 --allow-untrained``): these tests check exit codes,
messages and records, not fidelity.
"""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from cli_helpers import run_cli
from test_partial_failure import two_material_stage

from mtlx2neural.material_record import MaterialRecord
from mtlx2neural.pipeline import jobs
from mtlx2neural.pipeline.workers import run_jobs
from mtlx2neural.train.config import preset

GLAZE = '''
        def Material "Glaze"
        {
            token outputs:mtlx:surface.connect = </World/Looks/Glaze/SR.outputs:surface>
            def Shader "SR"
            {
                uniform token info:id = "ND_standard_surface_surfaceshader"
                color3f inputs:base_color = (0.9, 0.1, 0.1)
                float inputs:specular_roughness = 0.6
                token outputs:surface
            }
        }
'''
ARGS = ("--iterations", "0", "--allow-untrained", "--device", "cpu", "--workers", "1", "--quiet")


def _fail_training_of(monkeypatch, name: str, stub: bool = False) -> None:
    """``train_material`` raises the trainer's non-finite-loss error for the material ``name``;
    ``stub``: the others do not train either (a summary, no checkpoint: for tests that stop before
    the export or replace it)."""
    real = jobs.train_material

    def train(src, *args, **kwargs):
        if src.name == name:
            raise FloatingPointError("non-finite loss at step 3: {'loss_brdf': nan}")
        return (None, MaterialRecord(src.name, src.material, src.source_file, "")) if stub else real(src, *args, **kwargs)

    monkeypatch.setattr(jobs, "train_material", train)
    if stub:
        monkeypatch.setattr("mtlx2neural.pipeline.convert.load_checkpoint", lambda folder: None)


@pytest.mark.slow  # one untrained conversion (export, baseline fit, renders): tens of seconds on 2 cores
def test_a_material_whose_training_fails_is_skipped_and_the_other_exports(tmp_path, capsys, monkeypatch):
    from pxr import Sdf

    asset = tmp_path / "scene.usda"
    asset.write_text(two_material_stage(GLAZE, "Glaze"))
    _fail_training_of(monkeypatch, "/World/Looks/Glaze")
    code, out, err = run_cli(capsys, asset, *ARGS)
    assert code == 3, err
    assert "Traceback" not in err
    assert "mtlx2neural: skipped /World/Looks/Glaze:" in err and "non-finite loss" in err
    assert "FloatingPointError" in err
    assert "/World/Looks/Paint:" in out
    layer = Sdf.Layer.FindOrOpen(str(tmp_path / "scene_neural.usda"))
    record = dict(layer.customLayerData)["mtlx2neural"]
    assert list(record["materials"]) == ["/World/Looks/Paint"]
    assert "non-finite loss" in record["skippedMaterials"]["/World/Looks/Glaze"]
    assert layer.GetPrimAtPath("/World/Looks/Glaze") is None  # keeps its original network only
    folder = tmp_path / record["materials"]["/World/Looks/Paint"]["folder"]
    assert (folder / "neural" / "weights.json").is_file()


def test_library_result_lists_the_training_failure(tmp_path, monkeypatch):
    from mtlx2neural.pipeline import convert as pipeline_convert
    from mtlx2neural.pipeline.options import ConvertOptions

    asset = tmp_path / "scene.usda"
    asset.write_text(two_material_stage(GLAZE, "Glaze"))
    _fail_training_of(monkeypatch, "/World/Looks/Glaze", stub=True)
    exported = []
    monkeypatch.setattr(pipeline_convert, "_export",  # the export is the slow test's; here: what reaches it
                        lambda summaries, trained, *a: (exported.extend(t[1].material for t in trained),
                                                        (tmp_path / "layer.usda", [SimpleNamespace(notes=[])] * len(trained)))[1])
    options = ConvertOptions(train=preset("fast", iterations=0), allow_untrained=True, device="cpu", workers=1,
                             progress=False)
    summaries = pipeline_convert.convert_asset(asset, options)
    assert exported == ["/World/Looks/Paint"]
    assert [s.material for s in summaries] == ["/World/Looks/Paint"]
    (failure,) = summaries.failed
    assert failure["material"] == "/World/Looks/Glaze" and failure["node"] is None
    assert failure["reason"].startswith("training failed (FloatingPointError): non-finite loss")


def test_strict_training_failure_exits_2_and_writes_nothing(tmp_path, capsys, monkeypatch):
    asset = tmp_path / "scene.usda"
    asset.write_text(two_material_stage(GLAZE, "Glaze"))
    _fail_training_of(monkeypatch, "/World/Looks/Glaze", stub=True)
    code, out, err = run_cli(capsys, asset, "--strict", *ARGS)
    assert code == 2, err
    assert "Traceback" not in err and "--strict" in err and "/World/Looks/Glaze" in err
    assert "non-finite loss" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.usda"]


def test_nothing_trained_exits_2_and_writes_nothing(tmp_path, capsys, monkeypatch):
    asset = tmp_path / "scene.usda"
    asset.write_text(two_material_stage(GLAZE, "Glaze", paint=False))
    _fail_training_of(monkeypatch, "/World/Looks/Glaze")
    code, out, err = run_cli(capsys, asset, *ARGS)
    assert code == 2, err
    assert "no material could be converted" in err and "non-finite loss" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.usda"]


def test_run_jobs_reports_failures_and_never_swallows_an_interrupt(monkeypatch):
    from mtlx2neural.train.trainer import TrainingInterrupted

    def run(job):
        if job == "nan":
            raise FloatingPointError("non-finite loss")
        if job == "stop":
            raise TrainingInterrupted("interrupted")
        return {"material": job}

    monkeypatch.setattr("mtlx2neural.pipeline.workers.run_job", run)
    failed, done = [], []
    out = run_jobs(["a", "nan", "b"], 1, lambda i, s: done.append(i), lambda i, e: failed.append((i, str(e))))
    assert out == [{"material": "a"}, None, {"material": "b"}]
    assert failed == [(1, "non-finite loss")] and done == [0, 2]
    with pytest.raises(FloatingPointError):  # no failure callback: the first failure is raised
        run_jobs(["a", "nan"], 1)
    with pytest.raises(TrainingInterrupted):  # Ctrl-C stops everything, never a per-material failure
        run_jobs(["a", "stop", "b"], 1, failed=lambda i, e: failed.append(i))
