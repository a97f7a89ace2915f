"""Torch operators for MaterialX's two-value ramps and splits (``ramplr``, ``ramptb``, ``splitlr``,
``splittb``); ``ramp4`` expands through its library nodegraph.

``texcoord`` is MaterialX's uv (v up: "top" is v = 1).  A ramp blends linearly over [0, 1] of one
coordinate, clamped outside: ``ramplr`` from ``valuel`` at u = 0 to ``valuer`` at u = 1, ``ramptb`` from
``valueb`` at v = 0 to ``valuet`` at v = 1.  A split switches from the first value to the second where the
coordinate crosses ``center``.  MaterialX antialiases the switch over the pixel footprint (a smoothstep as
wide as the screen-space derivative of the coordinate); a point sample has no footprint, so here, as in
MaterialX's code with zero derivatives, it is a step: the second value where the coordinate > ``center``.
"""

from __future__ import annotations

from mtlx2neural.graph.ops import op


def _lerp(a, b, t):
    return a + (b - a) * t


op("ramplr")(lambda a, n: _lerp(a["valuel"], a["valuer"], a["texcoord"][:, 0:1].clamp(0.0, 1.0)))
op("ramptb")(lambda a, n: _lerp(a["valueb"], a["valuet"], a["texcoord"][:, 1:2].clamp(0.0, 1.0)))
op("splitlr")(lambda a, n: _lerp(a["valuel"], a["valuer"], (a["texcoord"][:, 0:1] > a["center"]).float()))
op("splittb")(lambda a, n: _lerp(a["valueb"], a["valuet"], (a["texcoord"][:, 1:2] > a["center"]).float()))
