"""Per-texel maps of every BSDF parameter that varies, and their prefiltered MIP pyramid.

``build_parameter_stack(compiled)`` evaluates the material's spatial sub-graph at
the texel centres of a grid as fine as its finest texture (taking UV tiling
into account), producing one channel group per *varying* parameter; constant
parameters stay constants. Levels are then built by filtering each group by
its meaning (see ``FILTERS``):

- colours, weights, scalars, IOR ...: box (2x2 average) - they act linearly on
  the BRDF, or close enough at the scale of one texel;
- microfacet normal, tangent and roughness: LEAN slope moments (:mod:`.lean`), so a
  coarse level holds one anisotropic, possibly tilted lobe that covers the bumps;
- other normals (diffuse lobes): box-averaged, then renormalised.

Maps are ``[C, H, W]`` float32 tensors with row 0 at the *top* of UV space
(v = 1), as image files store them. Parameter names are those of
``CompiledMaterial.parameters()``, so ``stack.sample(uv, level)`` can be passed
straight to ``ReferenceMaterial.eval(..., params=...)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F

from ..graph.compile import CompiledMaterial
from ..graph.ir import CHANNELS, Const
from .lean import lobe_from_moments, moments

MICROFACET = {"dielectric_bsdf", "conductor_bsdf", "generalized_schlick_bsdf"}
DEFAULT_PROCEDURAL_RES = 256
MAX_RES = 2048


@dataclass
class Channel:
    """One varying parameter: its name, width, meaning, filter, unit and observed range."""

    name: str
    width: int
    semantic: str   # color | weight | roughness | normal | tangent | scalar | vector
    filter: str     # box | lean | normalize
    unit: str
    range: tuple = (0.0, 0.0)


@dataclass
class ParameterStack:
    """Prefiltered parameter maps. ``levels[k]`` is ``[C, H_k, W_k]``; level 0 is the finest."""

    channels: list[Channel]
    levels: list[torch.Tensor]
    constants: dict = field(default_factory=dict)
    lean_groups: list[str] = field(default_factory=list)  # lobe paths whose normal/tangent/roughness are LEAN
    notes: list[str] = field(default_factory=list)

    @property
    def resolution(self) -> tuple[int, int]:
        return tuple(self.levels[0].shape[1:])

    def offsets(self) -> dict[str, slice]:
        out, o = {}, 0
        for c in self.channels:
            out[c.name] = slice(o, o + c.width)
            o += c.width
        return out

    def sample(self, uv: torch.Tensor, level: int = 0) -> dict:
        """Bilinear lookup of every varying parameter at ``uv`` [N,2] in MIP ``level``.

        UV space wraps (periodic), as the material's textures repeat. Returns
        ``{parameter name: [N, width]}``, including LEAN-derived normal/tangent/roughness.
        """
        return self._decode(_bilinear(self.levels[level], uv))

    def texel_values(self, level: int = 0) -> dict:
        """Every texel of ``level`` decoded as parameters: ``{name: [H*W, width]}`` (row-major, top row first)."""
        lv = self.levels[level]
        return self._decode(lv.reshape(lv.shape[0], -1).T)

    def _decode(self, flat: torch.Tensor) -> dict:
        out = {}
        for name, sl in self.offsets().items():
            out[name] = flat[:, sl]
        for lobe in self.lean_groups:
            n, t, a = lobe_from_moments(out.pop(f"{lobe}.#lean"))
            out[f"{lobe}.normal"], out[f"{lobe}.tangent"], out[f"{lobe}.roughness"] = n, t, a
        for c in self.channels:
            if c.filter == "normalize":
                v = out[c.name]
                out[c.name] = v / v.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        return out


def _bilinear(level: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """[C,H,W] map, [N,2] uv (bottom-left origin, periodic) -> [N,C]."""
    c, h, w = level.shape
    x = torch.remainder(uv[:, 0], 1.0) * w - 0.5
    y = (1.0 - torch.remainder(uv[:, 1], 1.0)) * h - 0.5
    x0, y0 = x.floor(), y.floor()
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.long(), y0.long()
    flat = level.reshape(c, -1)
    out = 0
    for dx, dy, wgt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        idx = torch.remainder(y0 + dy, h) * w + torch.remainder(x0 + dx, w)
        out = out + flat[:, idx].T * wgt
    return out


def _semantic(name: str, mx_type: str) -> tuple[str, str, str]:
    """(semantic, filter, unit) of a parameter from its input name and type."""
    leaf_input = name.rsplit(".", 1)[-1]
    if leaf_input in ("normal", "coat_normal"):
        return "normal", "normalize", "unit vector, local shading frame"
    if leaf_input == "tangent":
        return "tangent", "normalize", "unit vector, local shading frame"
    if leaf_input == "roughness":
        return "roughness", "box", "GGX alpha" if mx_type == "vector2" else "roughness"
    if mx_type == "color3":
        return "color", "box", "linear RGB, working space"
    if leaf_input in ("weight", "mix", "in2", "opacity"):
        return "weight", "box", "fraction"
    return ("scalar" if CHANNELS.get(mx_type, 1) == 1 else "vector"), "box", mx_type


def _texture_resolution(compiled: CompiledMaterial) -> tuple[int, int, list[str]]:
    """Finest texel grid over UV [0,1]^2: each image's size times its UV scale (tiling)."""
    import OpenImageIO as oiio

    g, ev, notes = compiled.graph, compiled.evaluator, []
    best = (0, 0)
    probe = torch.tensor([[0.25, 0.25], [0.75, 0.25], [0.25, 0.75]])
    for i in compiled.spatial_nodes:
        n = g[i]
        f = n.inputs.get("file")
        if n.category != "image" or not isinstance(f, Const) or not f.value:
            continue
        inp = oiio.ImageInput.open(f.value)
        if inp is None:
            continue
        w, h = inp.spec().width, inp.spec().height
        inp.close()
        tc = n.inputs["texcoord"]
        scale = (1.0, 1.0)
        if not isinstance(tc, Const):
            env = ev.run(ev.spatial_closure([tc]), probe)
            t = ev.value(tc, env)
            scale = (abs(float(t[1, 0] - t[0, 0])) * 2.0, abs(float(t[2, 1] - t[0, 1])) * 2.0)
        best = max(best, (int(math.ceil(h * max(scale[1], 1e-3))), int(math.ceil(w * max(scale[0], 1e-3)))))
    if best == (0, 0):
        best = (DEFAULT_PROCEDURAL_RES, DEFAULT_PROCEDURAL_RES)
        notes.append(f"no image textures: procedural inputs sampled on a {best[1]}x{best[0]} grid")
    if max(best) > MAX_RES:
        s = MAX_RES / max(best)
        notes.append(f"texel density {best[1]}x{best[0]} capped to {MAX_RES}: detail finer than "
                     f"1/{MAX_RES} of UV space is prefiltered")
        best = (max(1, int(best[0] * s)), max(1, int(best[1] * s)))
    return best[0], best[1], notes


def build_parameter_stack(compiled: CompiledMaterial, resolution: tuple[int, int] | None = None,
                          chunk: int = 1 << 16) -> ParameterStack:
    """Evaluate the varying parameters on a texel grid and build the prefiltered pyramid.

    ``resolution`` (H, W) overrides the automatic finest-texture grid.
    """
    ev = compiled.evaluator
    varying = compiled.varying_parameters()
    h, w, notes = _texture_resolution(compiled) if resolution is None else (*resolution, [])
    constants = {k: ev.value(i, {}) for k, i, _ in compiled.parameters() if k not in {v[0] for v in varying}}
    # Texel centres, row 0 at the top (v = 1).
    ys = 1.0 - (torch.arange(h, dtype=torch.float32) + 0.5) / h
    xs = (torch.arange(w, dtype=torch.float32) + 0.5) / w
    uv = torch.stack(torch.meshgrid(xs, ys, indexing="xy"), -1).reshape(-1, 2)
    nodes = ev.spatial_closure([i for _, i, _ in varying])
    values: dict[str, list[torch.Tensor]] = {k: [] for k, _, _ in varying}
    for s in range(0, uv.shape[0], chunk):
        env = ev.run(nodes, uv[s:s + chunk])
        for k, i, t in varying:
            v = ev.value(i, env)
            values[k].append(v.expand(min(chunk, uv.shape[0] - s), -1))
    texels = {k: torch.cat(v, 0) for k, v in values.items()}

    # LEAN: microfacet lobes whose normal or roughness varies keep slope moments instead.
    lean_groups = []
    leaf_cat = {leaf.path: leaf.category for leaf in compiled.program.leaves()}
    for lobe, cat in leaf_cat.items():
        if cat not in MICROFACET or not any(f"{lobe}.{p}" in texels for p in ("normal", "roughness", "tangent")):
            continue
        n = texels.pop(f"{lobe}.normal", None)
        a = texels.pop(f"{lobe}.roughness", None)
        texels.pop(f"{lobe}.tangent", None)
        count = uv.shape[0]
        n = constants.pop(f"{lobe}.normal").expand(count, 3) if n is None else n
        a = constants.pop(f"{lobe}.roughness").expand(count, 2) if a is None else a
        constants.pop(f"{lobe}.tangent", None)
        n = torch.where((n * n).sum(-1, keepdim=True) < 1e-12, torch.tensor([0.0, 0.0, 1.0]), n)
        texels[f"{lobe}.#lean"] = moments(n / n.norm(dim=-1, keepdim=True), a.clamp(1e-4, 1.0))
        lean_groups.append(lobe)

    channels = []
    types = {k: t for k, _, t in varying}
    for k, v in texels.items():
        if k.endswith(".#lean"):
            ch = Channel(k, 5, "lean_moments", "lean", "slope moments (sx, sy, Mxx, Myy, Mxy)")
        else:
            sem, filt, unit = _semantic(k, types[k])
            ch = Channel(k, v.shape[1], sem, filt, unit)
        ch.range = (float(v.min()), float(v.max()))
        channels.append(ch)
    if not channels:  # a uniform material: nothing varies, constants only
        return ParameterStack([], [torch.zeros(0, h, w)], constants, [], notes)
    level0 = torch.cat([texels[c.name] for c in channels], 1).T.reshape(-1, h, w).contiguous()
    levels = [level0]
    while levels[-1].shape[1] > 1 or levels[-1].shape[2] > 1:
        levels.append(F.avg_pool2d(levels[-1][None], 2, ceil_mode=True, count_include_pad=False)[0])
    return ParameterStack(channels, levels, constants, lean_groups, notes)
