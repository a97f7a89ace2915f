"""``time`` and ``frame`` fold to the instant the graph is compiled at (graph.ops.Application), carried
by the compiled graph (no module state): frame F, time F / fps seconds; a material that reads them gets
a note naming the frame."""

from __future__ import annotations

import MaterialX as mx
import pytest
import torch
from materials import FOOTER, HEADER, standard_surface

from mtlx2neural.graph import compile_material
from mtlx2neural.graph.node_eval import compile_output
from mtlx2neural.graph.ops import Application

NODES = HEADER + '''  <time name="t" type="float" />
  <frame name="f" type="float" />
  <multiply name="twice" type="float">
    <input name="in1" type="float" nodename="t" />
    <input name="in2" type="float" value="2.0" />
  </multiply>
''' + FOOTER
# base colour = (time, time, time) through convert, and specular roughness = frame / 100
MATERIAL = HEADER + '''  <time name="t" type="float" />
  <frame name="f" type="float" />
  <convert name="tc" type="color3">
    <input name="in" type="float" nodename="t" />
  </convert>
  <divide name="rough" type="float">
    <input name="in1" type="float" nodename="f" />
    <input name="in2" type="float" value="100.0" />
  </divide>
''' + standard_surface("Clock", "SR", base_color={"node": "tc"}, specular_roughness={"node": "rough", "type": "float"}) + FOOTER


def _doc(text: str) -> mx.Document:
    doc = mx.createDocument()
    mx.readFromXmlString(doc, text)
    return doc


@pytest.mark.parametrize("app", [Application(), Application(frame=48.0), Application(frame=7.5, fps=30.0)])
def test_time_and_frame_nodes_read_the_compiled_instant(app):
    doc = _doc(NODES)
    uv = torch.rand(5, 2, generator=torch.Generator().manual_seed(0))
    # exact: the op returns the float32 of frame and of frame / fps, and 2 * t is exact in float32
    assert torch.equal(compile_output(doc, "f", application=app)(uv), torch.full((5, 1), app.frame))
    assert torch.equal(compile_output(doc, "t", application=app)(uv),
                       torch.full((5, 1), app.frame / app.fps, dtype=torch.float32))
    assert torch.equal(compile_output(doc, "twice", application=app)(uv),
                       2 * torch.full((5, 1), app.frame / app.fps, dtype=torch.float32))


def test_two_instants_compile_independently():
    doc = _doc(NODES)
    early, late = compile_output(doc, "f", application=Application(frame=2.0)), compile_output(
        doc, "f", application=Application(frame=96.0))
    uv = torch.zeros(1, 2)
    assert float(early(uv)) == 2.0 and float(late(uv)) == 96.0  # no shared state between compilations
    assert float(compile_output(doc, "t")(uv)) == pytest.approx(1 / 24, rel=1e-6)  # default: frame 1, 24 fps


def _folded(compiled, category: str) -> float:
    (i,) = [i for i, n in enumerate(compiled.graph.nodes) if n.category == category]
    return float(compiled.evaluator.const[(i, "out")])


def test_material_bakes_base_colour_from_time_and_notes_the_frame():
    app = Application(frame=36.0, fps=24.0)
    compiled = compile_material(_doc(MATERIAL), "Clock", application=app)
    assert _folded(compiled, "time") == pytest.approx(1.5, rel=1e-7)  # 36 / 24 s, float32
    assert _folded(compiled, "frame") == 36.0
    assert compiled.reads_application == ["time", "frame"] and compiled.application == app
    values = {name: compiled.evaluator.value(inp, {}) for name, inp, _ in compiled.parameters()}
    colours = [v for k, v in values.items() if k.endswith(".color") and v.shape[-1] == 3]
    assert any(torch.allclose(v, torch.full_like(v, 1.5)) for v in colours), values  # time reaches base colour
    (note,) = [n for n in compiled.program.notes if "reads" in n]
    assert note.startswith("material Clock reads `time` and `frame`: baked at frame 36 (time 1.5 s")
    assert "--frame" in note


def test_a_material_without_time_has_no_note():
    compiled = compile_material(_doc(HEADER + standard_surface("Plain", "SR", base=0.5) + FOOTER), "Plain")
    assert compiled.reads_application == []
    assert not [n for n in compiled.program.notes if "--frame" in n]
