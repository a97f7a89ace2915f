"""compile_output (mtlx2neural.graph.node_eval): one node output evaluated at many points, and the explicit
per-point position that the evaluator accepts (default (u, v, 0))."""

from __future__ import annotations

import pytest
import torch

from mtlx2neural.errors import InputError
from mtlx2neural.graph.node_eval import compile_output

mx = pytest.importorskip("MaterialX")

XML = """<?xml version="1.0"?>
<materialx version="1.39">
  <position name="p" type="vector3"/>
  <texcoord name="t" type="vector2"/>
  <separate3 name="sp" type="multioutput"><input name="in" type="vector3" nodename="p"/></separate3>
  <add name="sum" type="float">
    <input name="in1" type="float" nodename="sp" output="outz"/>
    <input name="in2" type="float" value="1.5"/>
  </add>
  <constant name="k" type="color3"><input name="value" type="color3" value="0.1, 0.2, 0.3"/></constant>
  <nodegraph name="graph">
    <texcoord name="t2" type="vector2"/>
    <output name="out" type="vector2" nodename="t2"/>
  </nodegraph>
</materialx>
"""


def _doc():
    doc = mx.createDocument()
    mx.readFromXmlString(doc, XML)
    return doc


def test_position_is_explicit_or_uv_plane():
    g = torch.Generator().manual_seed(5)
    uv = torch.rand(64, 2, generator=g) * 4 - 2
    pos = torch.rand(64, 3, generator=g) * 10 - 5
    doc = _doc()
    p = compile_output(doc, "p")
    assert torch.equal(p(uv, pos), pos)
    assert torch.equal(p(uv), torch.cat([uv, torch.zeros(64, 1)], 1))  # default unchanged: (u, v, 0)
    # Exact: one float32 addition on each side.
    assert torch.equal(compile_output(doc, "sum")(uv, pos), pos[:, 2:3] + 1.5)
    assert torch.equal(compile_output(doc, "sp", "outx")(uv, pos), pos[:, :1])
    assert torch.equal(compile_output(doc, "graph")(uv, pos), uv)
    # A folded constant comes back with one row per point.
    k = compile_output(doc, "k")(uv)
    assert k.shape == (64, 3)
    torch.testing.assert_close(k[17], torch.tensor([0.1, 0.2, 0.3]))


def test_unknown_target_is_an_input_error():
    with pytest.raises(InputError):
        compile_output(_doc(), "missing")
