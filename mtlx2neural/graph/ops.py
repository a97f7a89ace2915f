"""Torch operators for MaterialX stdlib nodes (maths, logic, channel ops, geometry).

Each operator takes the node's resolved inputs as a dict of values and returns
its output (or a dict of outputs for multi-output nodes). Numeric values are
float32 tensors shaped ``[B, C]`` where ``B`` is 1 for constants or the batch
size, and ``C`` the MaterialX type's channel count; strings stay ``str``. Tensors
broadcast over ``B``, and a 1-channel value broadcasts over channels, which is
what MaterialX's "FA" (float second argument) variants need.

Semantics follow MaterialX's GLSL implementations. Every division, sqrt, log
and normalize is guarded so that no NaN or Inf leaves an operator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import torch

from mtlx2neural.graph.ir import CHANNELS

EPS = 1e-8  # guards for divisions/normalize; matches the role of M_FLOAT_EPS in MaterialX
OPS: dict[str, Callable] = {}


def op(*categories: str):
    def register(fn):
        for c in categories:
            OPS[c] = fn
        return fn
    return register


def safe_div(a, b):
    """a / b with b pushed away from 0 (sign kept), as a shader would guard it."""
    b = torch.where(b.abs() < EPS, torch.where(b < 0, -EPS, EPS) * torch.ones_like(b), b)
    return a / b


def normalize(v):
    """Unit vector along the last axis; zero vectors map to zero."""
    n = torch.linalg.vector_norm(v, dim=-1, keepdim=True)
    return v / n.clamp_min(EPS)


def dot(a, b):
    return (a * b).sum(-1, keepdim=True)


# --- arithmetic ---------------------------------------------------------------
op("add")(lambda a, n: a["in1"] + a["in2"])
op("subtract")(lambda a, n: a["in1"] - a["in2"])
op("multiply")(lambda a, n: a["in1"] * a["in2"])
op("divide")(lambda a, n: safe_div(a["in1"], a["in2"]))
op("modulo")(lambda a, n: a["in1"] - safe_div(a["in1"], a["in2"]).floor() * a["in2"])
op("absval")(lambda a, n: a["in"].abs())
op("sign")(lambda a, n: torch.sign(a["in"]))
op("floor")(lambda a, n: a["in"].floor())
op("ceil")(lambda a, n: a["in"].ceil())
op("fract")(lambda a, n: a["in"] - a["in"].floor())
op("round")(lambda a, n: a["in"].round())
op("invert")(lambda a, n: a["amount"] - a["in"])
op("min")(lambda a, n: torch.minimum(a["in1"], a["in2"]))
op("max")(lambda a, n: torch.maximum(a["in1"], a["in2"]))
op("clamp")(lambda a, n: torch.minimum(torch.maximum(a["in"], a["low"]), a["high"]))
op("mix")(lambda a, n: a["bg"] + (a["fg"] - a["bg"]) * a["mix"])
op("sqrt")(lambda a, n: a["in"].clamp_min(0.0).sqrt())
op("exp")(lambda a, n: a["in"].clamp(max=80.0).exp())
op("ln")(lambda a, n: a["in"].clamp_min(EPS).log())
op("sin")(lambda a, n: a["in"].sin())
op("cos")(lambda a, n: a["in"].cos())
op("tan")(lambda a, n: a["in"].tan())
op("asin")(lambda a, n: a["in"].clamp(-1, 1).asin())
op("acos")(lambda a, n: a["in"].clamp(-1, 1).acos())
op("atan2")(lambda a, n: torch.atan2(a["iny"], a["inx"]))


@op("power")
def _power(a, n):
    # GLSL pow(x, y) is undefined for x < 0; MaterialX graphs only feed x >= 0. Clamp like a GPU would.
    base = a["in1"].clamp_min(0.0)
    return torch.where(base > 0, base.clamp_min(1e-30).pow(a["in2"]), torch.zeros_like(base * a["in2"]))


@op("safepower")
def _safepower(a, n):
    x = a["in1"]
    return torch.sign(x) * x.abs().clamp_min(1e-30).pow(a["in2"]) * (x != 0)


@op("smoothstep")
def _smoothstep(a, n):
    # MaterialX: 1 from `high` up, 0 from `low` down (the first test wins when low > high), else the cubic.
    x, low, high = a["in"], a["low"], a["high"]
    t = safe_div(x - low, high - low).clamp(0, 1)
    smooth = t * t * (3 - 2 * t)
    return torch.where(x >= high, torch.ones_like(smooth), torch.where(x <= low, torch.zeros_like(smooth), smooth))


@op("remap")
def _remap(a, n):
    t = safe_div(a["in"] - a["inlow"], a["inhigh"] - a["inlow"])
    return a["outlow"] + t * (a["outhigh"] - a["outlow"])


# --- vectors --------------------------------------------------------------------
op("normalize")(lambda a, n: normalize(a["in"]))
op("magnitude")(lambda a, n: torch.linalg.vector_norm(a["in"], dim=-1, keepdim=True))
op("distance")(lambda a, n: torch.linalg.vector_norm(a["in1"] - a["in2"], dim=-1, keepdim=True))
op("dotproduct")(lambda a, n: dot(a["in1"], a["in2"]))
op("crossproduct")(lambda a, n: torch.linalg.cross(*torch.broadcast_tensors(a["in1"], a["in2"]), dim=-1))
op("luminance")(lambda a, n: torch.cat([dot(a["in"][:, :3], a["lumacoeffs"])] * 3
                                       + ([a["in"][:, 3:4]] if a["in"].shape[-1] == 4 else []), -1))


@op("rotate3d")
def _rotate3d(a, n):
    # Rodrigues' formula in MaterialX's row-vector convention: v' = v c + (v x k) s + k (k . v)(1 - c),
    # i.e. clockwise by `amount` degrees seen from the tip of `axis`.
    v, k = torch.broadcast_tensors(a["in"], normalize(a["axis"]))
    ang = a["amount"] * (math.pi / 180.0)
    c, s = ang.cos(), ang.sin()
    return v * c + torch.linalg.cross(v, k, dim=-1) * s + k * dot(k, v) * (1 - c)


@op("rotate2d")
def _rotate2d(a, n):
    # MaterialX's convention: clockwise by `amount` degrees, (c x + s y, -s x + c y).
    ang = a["amount"] * (math.pi / 180.0)
    c, s = ang.cos(), ang.sin()
    x, y = a["in"][:, :1], a["in"][:, 1:2]
    return torch.cat([c * x + s * y, -s * x + c * y], -1)


# --- channels ---------------------------------------------------------------------
@op("combine2", "combine3", "combine4")
def _combine(a, n):
    parts = [a[k] for k in ("in1", "in2", "in3", "in4") if k in a]
    batch = max(p.shape[0] for p in parts)  # broadcast the batch only: channels differ (color3 + float)
    return torch.cat([p.expand(batch, p.shape[1]) for p in parts], -1)
op("convert")(lambda a, n: _convert(a["in"], n.type))
op("constant", "dot")(lambda a, n: a["value"] if "value" in a else a["in"])


@op("extract")
def _extract(a, n):
    idx = int(a["index"].reshape(-1)[0].item())
    return a["in"][:, idx:idx + 1]


@op("separate2", "separate3", "separate4")
def _separate(a, n):
    return {name: a["in"][:, i:i + 1] for i, name in enumerate(n.outputs)}


def _convert(x, mx_type: str):
    """MaterialX's convert: to boolean, x != 0; a scalar fills every channel; extra channels are dropped;
    missing ones are 0 for z and 1 for w (vector2 -> vector4: (x, y, 0, 1))."""
    c = CHANNELS[mx_type]
    if mx_type == "boolean":
        return (x != 0).to(x.dtype)
    if x.shape[-1] == c:
        return x
    if x.shape[-1] == 1:
        return x.expand(x.shape[0], c)
    if x.shape[-1] > c:
        return x[:, :c]
    pad = [0.0, 0.0, 0.0, 1.0][x.shape[-1]:c]
    return torch.cat([x, torch.tensor([pad], dtype=x.dtype, device=x.device).expand(x.shape[0], -1)], -1)


# --- application state -----------------------------------------------------------------
@dataclass(frozen=True)
class Application:
    """The instant a baked material is one of: what ``frame`` and ``time`` fold to.

    ``frame``: the host's frame number (MaterialX's ``frame`` node; its nodedef's default is 1).
    ``fps``: frames per second; ``time`` (seconds, MaterialX's ``time`` node) is ``frame / fps``,
    USD's convention (time code / time codes per second). The ``time`` node's own ``fps`` input
    is not read: the specification marks it unused, to be removed.
    """

    frame: float = 1.0
    fps: float = 24.0

    @property
    def time(self) -> float:
        """Seconds: ``frame / fps``."""
        return self.frame / self.fps

    def value(self, category: str) -> float:
        """What a ``time`` or ``frame`` node returns at this instant."""
        return self.time if category == "time" else self.frame


APPLICATION_NODES = ("time", "frame")
DEFAULT_APPLICATION = Application()
"""The instant of a graph compiled without one (frame 1 at 24 fps)."""


def bake_application(graph, application: Application | None) -> list[str]:
    """Store ``application``'s value (None: :data:`DEFAULT_APPLICATION`) in every ``time``/``frame`` node
    of the IR ``graph`` (``attrs["application"]``, read by their operators when the graph is folded), so
    the compiled graph carries its instant; returns the categories the graph reads, in order."""
    application = application or DEFAULT_APPLICATION
    read = []
    for node in graph.nodes:
        if node.category in APPLICATION_NODES:
            node.attrs["application"] = repr(float(application.value(node.category)))
            if node.category not in read:
                read.append(node.category)
    return read


@op(*APPLICATION_NODES)
def _application(a, n):
    value = n.attrs.get("application")
    return torch.tensor([[float(value) if value is not None else DEFAULT_APPLICATION.value(n.category)]])


# --- logic ------------------------------------------------------------------------
def _choose(test, a):
    """in1 where ``test`` holds, else in2; the boolean nodedefs without in1/in2 return the test (1 or 0)."""
    if "in1" not in a:
        return test.float()
    return torch.where(test, a["in1"], a["in2"])


op("ifgreater")(lambda a, n: _choose(a["value1"] > a["value2"], a))
op("ifgreatereq")(lambda a, n: _choose(a["value1"] >= a["value2"], a))
op("ifequal")(lambda a, n: _choose(a["value1"] == a["value2"], a))
op("and")(lambda a, n: ((a["in1"] != 0) & (a["in2"] != 0)).float())
op("or")(lambda a, n: ((a["in1"] != 0) | (a["in2"] != 0)).float())
op("not")(lambda a, n: (a["in"] == 0).float())


@op("switch")
def _switch(a, n):
    which = a["which"].floor().clamp(0, 9)
    out = a["in1"]
    for i in range(2, 11):
        key = f"in{i}"
        if key in a and a[key] is not None:
            out = torch.where(which == i - 1, a[key], out)
    return out


# --- pbrlib parameter helpers (MaterialX genglsl semantics) -----------------------
@op("artistic_ior")
def _artistic_ior(a, n):
    """Gulbrandsen's artist-friendly conductor Fresnel: (reflectivity, edge_color) -> (ior, extinction)."""
    r = a["reflectivity"].clamp(0.0, 0.99)
    rs = r.sqrt()
    n_min = (1 - r) / (1 + r)
    n_max = (1 + rs) / (1 - rs)
    ior = n_max + (n_min - n_max) * a["edge_color"]
    k2 = (((ior + 1) ** 2) * r - (ior - 1) ** 2) / (1 - r)
    return {"ior": ior, "extinction": k2.clamp_min(0).sqrt()}


@op("roughness_anisotropy")
def _roughness_anisotropy(a, n):
    r2 = (a["roughness"] ** 2).clamp(1.1920929e-07, 1.0)
    aniso = a["anisotropy"]
    aspect = (1 - aniso.clamp(0, 0.98)).sqrt()
    ax = torch.where(aniso > 0, (r2 / aspect).clamp(max=1.0), r2)
    ay = torch.where(aniso > 0, r2 * aspect, r2)
    return torch.cat(torch.broadcast_tensors(ax, ay), -1)


@op("roughness_dual")
def _roughness_dual(a, n):
    r = a["roughness"]
    ry = torch.where(r[:, 1:2] < 0, r[:, :1], r[:, 1:2])
    return torch.cat([r[:, :1], ry], -1).pow(2).clamp(1.1920929e-07, 1.0)


@op("glossiness_anisotropy")
def _glossiness_anisotropy(a, n):
    return _roughness_anisotropy({"roughness": 1 - a["glossiness"], "anisotropy": a["anisotropy"]}, n)


@op("normalmap")
def _normalmap(a, n):
    """Tangent-space normal map decode, MaterialX 1.39 semantics (float or vector2 scale)."""
    v = a["in"]
    zero = (v * v).sum(-1, keepdim=True) == 0
    v = torch.where(zero, torch.tensor([0.0, 0.0, 1.0], dtype=v.dtype, device=v.device), v * 2 - 1)
    scale = a["scale"]
    sx, sy = (scale[:, :1], scale[:, 1:2]) if scale.shape[-1] == 2 else (scale, scale)
    out = a["tangent"] * v[:, :1] * sx + a["bitangent"] * v[:, 1:2] * sy + a["normal"] * v[:, 2:3]
    return normalize(out)




# --- colour models ---------------------------------------------------------------------
@op("rgbtohsv")
def _rgbtohsv(a, n):
    """RGB -> HSV with hue in [0, 1) (Foley and van Dam, as MaterialX's stdlib)."""
    x = a["in"]
    rgb = x[:, :3]
    r, g, b = rgb[:, 0:1], rgb[:, 1:2], rgb[:, 2:3]
    mx_, _ = rgb.max(-1, keepdim=True)
    mn, _ = rgb.min(-1, keepdim=True)
    delta = mx_ - mn
    s = torch.where(mx_ > 0, delta / mx_.clamp_min(EPS), torch.zeros_like(mx_))
    d = delta.clamp_min(EPS)
    h = torch.where(r >= mx_, (g - b) / d, torch.where(g >= mx_, 2.0 + (b - r) / d, 4.0 + (r - g) / d)) / 6.0
    h = torch.where(h < 0, h + 1.0, h)
    h = torch.where(delta > 0, h, torch.zeros_like(h))
    return torch.cat([h, s, mx_, x[:, 3:]], -1)


@op("hsvtorgb")
def _hsvtorgb(a, n):
    """HSV (hue in [0, 1)) -> RGB."""
    x = a["in"]
    h, s, v = x[:, 0:1], x[:, 1:2], x[:, 2:3]
    h6 = 6.0 * (h - h.floor())
    hi = h6.floor().clamp(0, 5)
    f = h6 - hi
    p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    table = [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)]
    out = torch.cat(table[0], -1)
    for i in range(1, 6):
        out = torch.where(hi == i, torch.cat(table[i], -1), out)
    out = torch.where(s < 0.0001, torch.cat([v, v, v], -1), out)
    return torch.cat([out, x[:, 3:]], -1)
