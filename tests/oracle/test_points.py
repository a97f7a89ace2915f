"""Tests for the per-point node oracle (mtlx2neural.oracle.points.mtlx_node_eval).

Each distinct (document, node) costs one Slang compile (a few seconds on a 2-core CPU); this file compiles
four.  Everything is skipped when slangpy's CPU device is unavailable.
"""

from __future__ import annotations

import numpy as np
import pytest

from mtlx2neural.oracle.errors import OracleError
from mtlx2neural.oracle.points import mtlx_node_eval
from mtlx2neural.oracle.runner import oracle_available

mx = pytest.importorskip("MaterialX")


@pytest.fixture(scope="module", autouse=True)
def _require_oracle():
    ok, reason = oracle_available()
    if not ok:
        pytest.skip(f"MaterialX Slang oracle unavailable: {reason}")


GEOMETRY = """<?xml version="1.0"?>
<materialx version="1.39">
  <position name="p" type="vector3"/>
  <position name="pw" type="vector3"><input name="space" type="string" value="world"/></position>
  <texcoord name="t" type="vector2"/>
  <normal name="nrm" type="vector3"/>
  <separate2 name="st" type="multioutput"><input name="in" type="vector2" nodename="t"/></separate2>
  <separate3 name="sp" type="multioutput"><input name="in" type="vector3" nodename="pw"/></separate3>
  <combine4 name="mixed" type="vector4">
    <input name="in1" type="float" nodename="st" output="outy"/>
    <input name="in2" type="float" nodename="sp" output="outz"/>
    <input name="in3" type="float" nodename="st" output="outx"/>
    <input name="in4" type="float" nodename="sp" output="outx"/>
  </combine4>
  <nodegraph name="graph">
    <texcoord name="t2" type="vector2"/>
    <multiply name="twice" type="vector2">
      <input name="in1" type="vector2" nodename="t2"/>
      <input name="in2" type="float" value="2.0"/>
    </multiply>
    <output name="out" type="vector2" nodename="twice"/>
  </nodegraph>
</materialx>
"""


def _doc(xml: str):
    doc = mx.createDocument()
    mx.readFromXmlString(doc, xml)
    return doc


def _points(n: int, seed: int):
    # float32-representable inputs so that the float32 kernel sees exactly these values
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-4.0, 4.0, (n, 2)).astype(np.float32).astype(np.float64)
    pos = rng.uniform(-5.0, 5.0, (n, 3)).astype(np.float32).astype(np.float64)
    return uv, pos


def test_geometry_reaches_every_point_exactly():
    uv, pos = _points(100, seed=1)
    doc = _doc(GEOMETRY)
    # A pure copy of the inputs through extract/combine: exact (no arithmetic), so tolerance 0.
    got = mtlx_node_eval(doc, "mixed", uv, pos)
    assert got.shape == (100, 4) and got.dtype == np.float64
    np.testing.assert_array_equal(got, np.stack([uv[:, 1], pos[:, 2], uv[:, 0], pos[:, 0]], 1))
    # Object space (the default) and world space coincide: the probe has no transform.
    np.testing.assert_array_equal(mtlx_node_eval(doc, "p", uv, pos), pos)
    # A multi-output node's named output.
    np.testing.assert_array_equal(mtlx_node_eval(doc, "st", uv, pos, output="outy"), uv[:, 1:2])


def test_nodegraph_output_and_normal():
    uv, pos = _points(64, seed=2)
    doc = _doc(GEOMETRY)
    # Multiplying by 2 is exact in float32.
    np.testing.assert_array_equal(mtlx_node_eval(doc, "graph", uv, pos), 2.0 * uv)
    np.testing.assert_array_equal(mtlx_node_eval(doc, "graph/out", uv[:3], pos[:3]), 2.0 * uv[:3])
    normals = np.tile([0.0, 0.6, 0.8], (64, 1))
    got = mtlx_node_eval(doc, "nrm", uv, pos, normal=normals)
    # MaterialX normalises the interpolated normal in float32: a few ulps.
    np.testing.assert_allclose(got, normals, atol=1e-6)
    np.testing.assert_allclose(mtlx_node_eval(doc, "nrm", uv, pos), np.tile([0.0, 0.0, 1.0], (64, 1)), atol=1e-7)


def test_input_validation():
    doc = _doc(GEOMETRY)
    uv, pos = _points(4, seed=3)
    with pytest.raises(ValueError):
        mtlx_node_eval(doc, "p", uv, pos[:3])
    with pytest.raises(ValueError):
        mtlx_node_eval(doc, "p", uv[:, :1], pos)
    with pytest.raises(ValueError):
        mtlx_node_eval(doc, "p", np.full((4, 2), np.nan), pos)
    with pytest.raises(OracleError):
        mtlx_node_eval(doc, "no_such_node", uv, pos)
    with pytest.raises(OracleError):
        mtlx_node_eval(doc, "st", uv, pos, output="outq")


def test_many_targets_share_one_shader():
    uv, pos = _points(64, seed=4)
    doc = _doc(GEOMETRY)
    got = mtlx_node_eval(doc, ["mixed", ("sp", "outy"), "t", "p"], uv, pos)
    assert [g.shape for g in got] == [(64, 4), (64, 1), (64, 2), (64, 3)]
    # Pure copies of the inputs: exact.
    np.testing.assert_array_equal(got[0], np.stack([uv[:, 1], pos[:, 2], uv[:, 0], pos[:, 0]], 1))
    np.testing.assert_array_equal(got[1], pos[:, 1:2])
    np.testing.assert_array_equal(got[2], uv)
    np.testing.assert_array_equal(got[3], pos)
