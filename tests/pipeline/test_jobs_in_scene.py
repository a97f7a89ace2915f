"""The conversion's in-scene fidelity: a USD stage with a bound quad, a camera and a distant light gets
``flip_in_scene`` (and how it was viewed and lit) in summary.json and the layer beside ``flip_mean``,
and ``--max-error`` checks that figure. Tiny trainings (4 steps of 128 samples, no preview fit) and
small renders: the decisions are checked, not the fidelity; about 30 s on 2 shared cores."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest

from mtlx2neural.commands.convert import print_summaries
from mtlx2neural.material_record import MaterialRecord
from mtlx2neural.pipeline import budget, in_scene_measure, material_training
from mtlx2neural.pipeline.convert import convert_asset
from mtlx2neural.pipeline.in_scene_measure import measure_in_scene
from mtlx2neural.pipeline.options import ConvertOptions
from mtlx2neural.train.config import preset

pytest.importorskip("pxr", reason="usd-core is needed for a USD stage")

TINY = preset("fast", iterations=4, batch=128, preview_iterations=0)

STAGE = """#usda 1.0
(
    upAxis = "Y"
)
def Xform "World"
{
    def Mesh "Quad" (prepend apiSchemas = ["MaterialBindingAPI"])
    {
        point3f[] points = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (interpolation = "vertex")
        rel material:binding = </World/Looks/M>
    }
    def Camera "Cam"
    {
        double3 xformOp:translate = (0, 0, 6)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    def DistantLight "Sun"
    {
        float inputs:intensity = 2
        float xformOp:rotateX = -30
        uniform token[] xformOpOrder = ["xformOp:rotateX"]
    }
    def Scope "Looks"
    {
        def Material "M"
        {
            token outputs:mtlx:surface.connect = </World/Looks/M/SR.outputs:out>
            def Shader "SR"
            {
                uniform token info:id = "ND_standard_surface_surfaceshader"
                color3f inputs:base_color = (0.7, 0.3, 0.2)
                float inputs:specular_roughness = 0.3
                token outputs:out
            }
        }
    }
}
"""


def small_renders(monkeypatch) -> None:
    """Both measures at 32 px and 4 samples: these tests check what is recorded and decided, not the
    figures' precision (the defaults take ~10x longer on 2 shared cores)."""
    views, in_scene = material_training.summary_views, in_scene_measure.compare_in_scene
    monkeypatch.setattr(material_training, "summary_views", lambda *a, **k: views(*a, **k, res=32, spp=4))
    monkeypatch.setattr(in_scene_measure, "compare_in_scene", lambda *a, **k: in_scene(*a, **k, res=32, spp=4))


def test_summary_and_layer_record_the_in_scene_figure_and_the_budget_uses_it(tmp_path, monkeypatch, capsys):
    asset = tmp_path / "scene.usda"
    asset.write_text(STAGE)
    small_renders(monkeypatch)
    # flagged="neural": a tiny training fails the quality gate; the test reads the neural variant's attributes
    first = convert_asset(asset, ConvertOptions(train=TINY, progress=False, device="cpu", workers=1,
                                                 flagged="neural"))
    (s,) = first
    flip = s.flip_in_scene
    assert 0.0 < flip < 1.0 and math.isfinite(s.flip_mean)  # both figures, side by side
    rec = s.in_scene
    assert rec["measured"] and rec["camera"].startswith("/World/Cam") and rec["prims"] == ["/World/Quad"]
    assert rec["lights"][0].startswith("/World/Sun: distant") and rec["triangles"] == 2
    assert (rec["res"], rec["spp"]) == (32, 4)
    # USD's default lens at 6 units spans +-0.92: the quad (+-1) fills the image.
    assert rec["coverage"] > 0.95
    folder = tmp_path / "scene_neural" / "World.Looks.M"
    assert json.loads((folder / "summary.json").read_text())["flip_in_scene"] == flip
    assert (folder / "in_scene_reference.png").is_file() and (folder / "in_scene_neural.png").is_file()
    from pxr import Usd

    layer = Usd.Stage.Open(str(tmp_path / "scene_neural.usda"))
    # float32 in the layer against the summary's 4 decimals.
    assert layer.GetPrimAtPath("/World/Looks/M").GetAttribute("neural:metrics:flipInScene").Get() == \
        pytest.approx(flip, abs=1e-6)

    # --max-error checks the in-scene figure: made exact (0), it meets a budget of 1e-9 with the
    # smallest decoder, which the analytic views' figure (> 0 after 4 steps) would miss with all three.
    real = in_scene_measure.compare_in_scene

    def exact(*args, **kwargs):
        return {label: {**r, "flip": 0.0} for label, r in real(*args, **kwargs).items()}

    monkeypatch.setattr(in_scene_measure, "compare_in_scene", exact)
    trained = []
    train = budget.train_material
    monkeypatch.setattr(budget, "train_material", lambda src, cfg, *a, **k: trained.append(cfg.decoder)
                        or train(src, cfg, *a, **k))
    budgeted = convert_asset(asset, ConvertOptions(train=TINY, progress=False, device="cpu", workers=1,
                                                   max_error=1e-9))
    (b,) = budgeted
    assert trained == ["2x16"] and b.decoder == "2x16" and b.budget_met is True
    assert b.budget["metric"] == "flip_in_scene" and b.budget["flip_by_decoder"] == {"2x16": 0.0}
    assert b.flip_mean > 1e-9  # the analytic figure, still recorded, would have missed the budget
    capsys.readouterr()
    print_summaries(first)
    print_summaries(budgeted)
    out = capsys.readouterr().out  # the command's report names both figures and the one budgeted
    assert f"in scene {flip:.4f}" in out and "budget HDR FLIP in scene <= 1e-09: met" in out


def test_mtlx_input_has_no_in_scene_figure_and_budgets_on_the_analytic_views():
    """A .mtlx source (no stage file, no bound prims) gets no in-scene entry, so the summary is as before
    (the .mtlx conversions of tests/pipeline/test_jobs.py check the rest)."""

    class Src:
        stage_file, bound_prims = None, []

    assert measure_in_scene(None, {}, (1, 1), Src()) == {}
    record = MaterialRecord("M", "M", "m.mtlx", "", flip_mean=0.2)
    assert record.budget_error() == 0.2
    assert dataclasses.replace(record, flip_in_scene=0.3).budget_error() == 0.3


def test_a_scene_showing_nothing_lit_records_why_and_no_figure(tmp_path, monkeypatch):
    """The stage's only light shines on the quad's back: every pixel is black in both renders, so there
    is no in-scene figure (FLIP of two black images would read as a perfect 0) and the budget falls
    back to the analytic views."""
    import torch

    class Grey:
        def eval(self, wi, wo, at=None):
            return torch.full((len(wi), 3), 0.2)

    asset = tmp_path / "behind.usda"
    asset.write_text(STAGE.replace("float xformOp:rotateX = -30", "float xformOp:rotateX = 180"))

    class Src:
        stage_file, bound_prims = str(asset), ["/World/Quad"]

    small_renders(monkeypatch)
    out = measure_in_scene(Grey(), {"neural": Grey()}, (1, 1), Src())
    assert "flip_in_scene" not in out and out["in_scene"]["measured"] is False
    assert "shows nothing lit" in out["in_scene"]["why"] and out["in_scene"]["camera"].startswith("/World/Cam")
    assert MaterialRecord("M", "M", "m.usda", "", flip_mean=0.2, **out).budget_error() == 0.2
