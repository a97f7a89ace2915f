"""Torch operators for MaterialX's compositing nodes (stdlib nodegroup "compositing").

Values are ``[B, C]`` float32 tensors as in :mod:`mtlx2neural.graph.ops`: ``fg`` and ``bg`` are float,
color3 or color4 (the alpha-aware nodes ``over``, ``disjointover``, ``in``, ``out``, ``mask``, ``matte``,
``premult`` and ``unpremult`` are color4 only, alpha in the last channel, colours premultiplied as
MaterialX assumes), ``mix`` is a float in [0, 1] that blends the composite with ``bg`` (1: the composite
only).  ``inside``/``outside`` scale ``in`` by a float ``mask``.

The arithmetic follows MaterialX's shader implementations (the same float32 expressions in the same
order); ``burn``, ``dodge``, ``disjointover`` and ``unpremult`` divide, and where MaterialX's code
returns a fixed value for a zero divisor (``|d| < 1e-8``) so do these.  ``unpremult`` of a zero alpha is
an Inf in MaterialX; here the divisor is pushed to +-1e-8 instead, so no Inf leaves the operator.
"""

from __future__ import annotations

import torch

from mtlx2neural.graph.ops import EPS, op, safe_div


def _blend(result, a):
    """The composite blended with the background by ``mix``: mix * result + (1 - mix) * bg."""
    m = a["mix"]
    return m * result + (1.0 - m) * a["bg"]


op("plus")(lambda a, n: _blend(a["bg"] + a["fg"], a))
op("minus")(lambda a, n: _blend(a["bg"] - a["fg"], a))
op("difference")(lambda a, n: _blend((a["bg"] - a["fg"]).abs(), a))
op("screen")(lambda a, n: _blend(1.0 - (1.0 - a["fg"]) * (1.0 - a["bg"]), a))
op("inside")(lambda a, n: a["in"] * a["mask"])
op("outside")(lambda a, n: a["in"] * (1.0 - a["mask"]))


@op("burn")
def _burn(a, n):
    """Colour burn per channel (alpha included): 1 - (1 - bg) / fg; 0 where |fg| < 1e-8."""
    fg, bg = torch.broadcast_tensors(a["fg"], a["bg"])
    out = _blend(1.0 - safe_div(1.0 - bg, fg), a)
    return torch.where(fg.abs() < EPS, torch.zeros_like(out), out)


@op("dodge")
def _dodge(a, n):
    """Colour dodge per channel (alpha included): bg / (1 - fg); 0 where |1 - fg| < 1e-8."""
    fg, bg = torch.broadcast_tensors(a["fg"], a["bg"])
    d = 1.0 - fg
    out = _blend(safe_div(bg, d), a)
    return torch.where(d.abs() < EPS, torch.zeros_like(out), out)


def _alpha(x):
    return x[:, 3:4]


op("over")(lambda a, n: _blend(a["fg"] + a["bg"] * (1.0 - _alpha(a["fg"])), a))
op("in")(lambda a, n: _blend(a["fg"] * _alpha(a["bg"]), a))
op("out")(lambda a, n: _blend(a["fg"] * (1.0 - _alpha(a["bg"])), a))
op("mask")(lambda a, n: _blend(a["bg"] * _alpha(a["fg"]), a))


@op("matte")
def _matte(a, n):
    """fg matted over bg with fg's alpha as coverage (rgb: fg.rgb * fg.a + bg.rgb * (1 - fg.a))."""
    fg, bg = a["fg"], a["bg"]
    fa = _alpha(fg)
    rgb = fg[:, :3] * fa + bg[:, :3] * (1.0 - fa)
    alpha = fa + _alpha(bg) * (1.0 - fa)
    return _blend(torch.cat([rgb, alpha], -1), a)


@op("disjointover")
def _disjointover(a, n):
    """fg over bg, the two coverages treated as disjoint: rgb fg + bg where the alphas sum to <= 1, else
    fg + bg * (1 - fg.a) / bg.a (0 where |bg.a| < 1e-8); alpha min(fg.a + bg.a, 1)."""
    fg, bg = torch.broadcast_tensors(a["fg"], a["bg"])
    fa, ba = _alpha(fg), _alpha(bg)
    total = fa + ba
    scaled = fg[:, :3] + bg[:, :3] * safe_div(1.0 - fa, ba)
    scaled = torch.where(ba.abs() < EPS, torch.zeros_like(scaled), scaled)
    rgb = torch.where(total <= 1.0, fg[:, :3] + bg[:, :3], scaled)
    return _blend(torch.cat([rgb, total.clamp(max=1.0)], -1), a)


op("premult")(lambda a, n: torch.cat([a["in"][:, :3] * _alpha(a["in"]), _alpha(a["in"])], -1))
op("unpremult")(lambda a, n: torch.cat([safe_div(a["in"][:, :3], _alpha(a["in"])), _alpha(a["in"])], -1))
