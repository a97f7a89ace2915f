"""Per-texel maps of every BSDF parameter that varies, and their prefiltered MIP pyramid.

``build_parameter_stack(compiled)`` evaluates the material's spatial sub-graph at
the texel centres of a grid as fine as its finest texture (taking UV tiling
into account), producing one channel group per *varying* parameter; constant
parameters stay constants. A graph that reads geometry (position, normal,
primvars: :func:`mtlx2neural.graph.geometry.bind_geometry`) reads the bound
meshes rasterised at that same grid (:mod:`mtlx2neural.scene.uv_raster`), so each
sample sits on a texel centre of the geometry maps. Levels are then built by filtering each group by
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

from mtlx2neural.graph.compile import CompiledMaterial
from mtlx2neural.graph.ir import CHANNELS, Const
from mtlx2neural.imaging.grid_lookup import bilinear_periodic
from mtlx2neural.imaging.image_io import openimageio, pending_oiio_error
from mtlx2neural.imaging.udim import discover_tiles, is_tiled_path
from mtlx2neural.textures.lean import lobe_from_moments, moments

MICROFACET = {"dielectric_bsdf", "conductor_bsdf", "generalized_schlick_bsdf"}
DEFAULT_PROCEDURAL_RES = 256
MAX_RES = 8192  # finest grid kept; denser texel densities are prefiltered down to it
LEAN_TANGENT = True
"""The lobe's tangent (the compiled leaf's ``tangent`` input, which the shading models' graphs build from
standard_surface's ``specular_rotation``/``coat_rotation`` (0-1 = 0-360 degrees) and ``tangent``, open_pbr's
``geometry_tangent``/``geometry_coat_tangent``, gltf_pbr's ``anisotropy_rotation``) rotates its LEAN slope
covariance (:func:`.lean.moments`), so level 0 keeps a rotated anisotropic lobe's orientation and a
coarse level's anisotropy falls where rotations vary. ``False``: alphas along the geometric x/y axes,
the path before 2026-12-02, kept for the measurement in docs/history/paper-choices-2026-12-02.md."""


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
    texel_ratio: tuple[float, float] = (1.0, 1.0)
    """Native texels (of the finest texture) per level-0 texel, (rows, columns); > 1 when the
    grid was capped below the textures' resolution, so level 0 is already a filtered version."""

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
        return self._decode(bilinear_periodic(self.levels[level], uv))

    def native_params_at(self):
        """``uv [M, 2] -> {name: [M, width]}``: the reference's parameters at points, read from level 0, when the
        stack holds the textures at their own resolution (``texel_ratio`` 1); None when points must evaluate the
        material graph instead (a grid capped below the textures, or a material with no varying channels). The
        energy check and the energy balance read their footprint points through it, as the training targets do."""
        if not self.channels or self.texel_ratio != (1.0, 1.0):
            return None
        return lambda uv: self.sample(uv, 0)

    def sample_raw(self, uv: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
        """Undecoded channels [N, C] (LEAN moments, not lobes) at ``uv`` with per-query integer
        ``level`` [N]: the encoder's input. [N, 0] for a uniform material."""
        out = torch.zeros(uv.shape[0], self.levels[0].shape[0], dtype=torch.float32, device=uv.device)
        if out.shape[1] == 0:
            return out
        for k in torch.unique(level).tolist():
            idx = torch.nonzero(level == k)[:, 0]
            out[idx] = bilinear_periodic(self.levels[int(k)], uv[idx]).float()
        return out

    def texel_values(self, level: int = 0) -> dict:
        """Every texel of ``level`` decoded as parameters: ``{name: [H*W, width]}`` (row-major, top row first)."""
        lv = self.levels[level]
        return self._decode(lv.reshape(lv.shape[0], -1).T)

    def decode(self, flat: torch.Tensor) -> dict:
        """Raw channels [N, C] (``sample_raw``'s) decoded as parameters: ``{name: [N, width]}``, each LEAN
        lobe's moments as its ``normal``, ``tangent`` and ``roughness`` (GGX alpha_x, alpha_y)."""
        return self._decode(flat)

    def _decode(self, flat: torch.Tensor) -> dict:
        flat = flat.float()
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



def uniform_stack() -> ParameterStack:
    """The stack of a material without varying parameters: no channels, one 1x1 level."""
    return ParameterStack(channels=[], levels=[torch.zeros(0, 1, 1)])


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


def texture_resolution(compiled: CompiledMaterial) -> tuple[int, int, list[str]]:
    """Finest texel grid over UV [0,1]^2: each image's size times its UV scale (tiling); a UDIM set
    counts with its largest tile (the grid of one tile, which spans one uv unit)."""

    oiio = openimageio()
    g, ev, notes = compiled.graph, compiled.evaluator, []
    best = (0, 0)
    probe = torch.tensor([[0.25, 0.25], [0.75, 0.25], [0.25, 0.75]])
    for i in compiled.all_spatial_nodes:  # emission and opacity textures count too
        n = g[i]
        f = n.inputs.get("file")
        if n.category != "image" or not isinstance(f, Const) or not f.value:
            continue
        if n.attrs.get("missing"):
            continue  # a missing texture: its default is used
        # A UDIM set: its largest tile (one tile spans one uv unit, as one image spans [0,1]).
        files = list(discover_tiles(f.value).values()) if is_tiled_path(f.value) else [f.value]
        w = h = 0
        for path in files:
            inp = oiio.ImageInput.open(path)
            if inp is None:
                pending_oiio_error(f"texture '{path}' of '{n.path}'")  # retrieved: OIIO would print it at exit
                continue
            w, h = max(w, inp.spec().width), max(h, inp.spec().height)
            inp.close()
        if (w, h) == (0, 0):
            continue
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


STORAGE_BUDGET_BYTES = 2 << 30  # level 0 above this is stored as float16 (pyramid ~ 4/3 of level 0)


def _layout(compiled: CompiledMaterial):
    """Channel plan: (varying parameters by name, LEAN lobe paths, [(name, width, mx type)])."""
    varying = {k: (i, t) for k, i, t in compiled.varying_parameters()}
    lean, plan = [], []
    for leaf in compiled.program.leaves():
        if leaf.category in MICROFACET and any(f"{leaf.path}.{p}" in varying for p in ("normal", "roughness", "tangent")):
            lean.append(leaf.path)
    lean_keys = {f"{lobe}.{p}" for lobe in lean for p in ("normal", "roughness", "tangent")}
    for k, (inp, t) in varying.items():
        if k not in lean_keys:
            plan.append((k, CHANNELS.get(t, 1), t))
    plan += [(f"{lobe}.#lean", 5, "lean") for lobe in lean]
    return varying, lean, plan


MAX_SUPERSAMPLE = 16  # sub-texel samples per axis when a capped grid prefilters finer textures


def build_parameter_stack(compiled: CompiledMaterial, resolution: tuple[int, int] | None = None,
                          chunk_rows: int | None = None, storage_dtype: torch.dtype | None = None) -> ParameterStack:
    """Evaluate the varying parameters on a texel grid and build the prefiltered pyramid.

    ``resolution`` (H, W) overrides the automatic finest-texture grid. A grid
    coarser than the textures is *prefiltered*, not point-sampled: each level-0
    texel averages an s x s grid of sub-texel samples (s = native texels per
    texel, at most ``MAX_SUPERSAMPLE``), box or LEAN by channel, exactly as the
    coarser MIP levels are built. Level 0 is filled in row chunks straight into
    its final tensor, so peak memory stays near the pyramid's own size.
    ``storage_dtype`` defaults to float32, or float16 when level 0 would exceed
    ``STORAGE_BUDGET_BYTES`` (lookups return float32).
    """
    ev = compiled.evaluator
    varying, lean, plan = _layout(compiled)
    if resolution is None:
        h, w, notes = texture_resolution(compiled)
        ratio = (1.0, 1.0)
    else:
        h, w = resolution
        notes = []
        if plan:
            nh, nw, _ = texture_resolution(compiled)
            ratio = (max(1.0, nh / h), max(1.0, nw / w))
        else:
            ratio = (1.0, 1.0)
    ss = (min(MAX_SUPERSAMPLE, math.ceil(ratio[0] - 1e-6)), min(MAX_SUPERSAMPLE, math.ceil(ratio[1] - 1e-6)))
    if ss != (1, 1):
        notes.append(f"{w}x{h} grid below the textures' {round(w * ratio[1])}x{round(h * ratio[0])}: "
                     f"level 0 averages {ss[1]}x{ss[0]} samples per texel")
    inputs = {k: i for k, i, _ in compiled.parameters()}
    constants = {k: ev.value(i, {}) for k, i in inputs.items() if k not in varying}
    for lobe in lean:  # LEAN lobes take normal/roughness/tangent from the moments, never from constants
        for p in ("normal", "roughness", "tangent"):
            constants.pop(f"{lobe}.{p}", None)
    if not plan:  # a uniform material: nothing varies, constants only
        return ParameterStack([], [torch.zeros(0, h, w)], constants, [], notes, ratio)
    total = sum(width for _, width, _ in plan)
    if storage_dtype is None:
        storage_dtype = torch.float16 if total * h * w * 4 > STORAGE_BUDGET_BYTES else torch.float32
        if storage_dtype == torch.float16:
            notes.append(f"{total} channels at {w}x{h} exceed {STORAGE_BUDGET_BYTES >> 30} GiB in float32: "
                         f"stored as float16")
    level0 = torch.empty(total, h, w, dtype=storage_dtype)
    lo = torch.full((total,), float("inf"))
    hi = torch.full((total,), float("-inf"))
    nodes = ev.spatial_closure([inp for inp, _ in varying.values()])
    sy, sx = ss
    if ev.geometry is not None:  # geometry drawn at the sample grid: every sample reads a texel centre
        ev.geometry.resolution = (h * sy, w * sx)
    # Sub-texel sample positions: an sy x sx grid of cell centres inside each texel.
    xs = ((torch.arange(w * sx, dtype=torch.float32) + 0.5) / (w * sx)).view(w, sx)
    rows = chunk_rows or max(1, (1 << 16) // (w * sx * sy))
    z = torch.tensor([0.0, 0.0, 1.0])
    for r0 in range(0, h, rows):
        r1 = min(h, r0 + rows)
        ys = 1.0 - ((torch.arange(r0 * sy, r1 * sy, dtype=torch.float32) + 0.5) / (h * sy)).view(r1 - r0, sy)
        # Order (row, col, sub-row, sub-col) so each texel's samples are contiguous.
        uv = torch.stack([xs[None, :, None, :].expand(r1 - r0, w, sy, sx),
                          ys[:, None, :, None].expand(r1 - r0, w, sy, sx)], -1).reshape(-1, 2)
        count = uv.shape[0]
        env = ev.run(nodes, uv)

        def get(key, default_width):
            if key in varying:
                return ev.value(varying[key][0], env).expand(count, -1)
            c = ev.value(inputs[key], {})
            return c.expand(count, default_width)

        parts = []
        for name, width, _ in plan:
            if name.endswith(".#lean"):
                lobe = name[: -len(".#lean")]
                n = get(f"{lobe}.normal", 3)
                a = get(f"{lobe}.roughness", 2)
                n = torch.where((n * n).sum(-1, keepdim=True) < 1e-12, z, n)
                t = get(f"{lobe}.tangent", 3) if LEAN_TANGENT else None
                parts.append(moments(n / n.norm(dim=-1, keepdim=True), a.clamp(1e-4, 1.0), t))
            else:
                parts.append(get(name, width))
        block = torch.cat(parts, 1)  # [count, C]
        if sy * sx > 1:  # box / LEAN-moment average of each texel's sub-samples
            block = block.view(-1, sy * sx, block.shape[1]).mean(1)
        lo = torch.minimum(lo, block.min(0).values)
        hi = torch.maximum(hi, block.max(0).values)
        level0[:, r0:r1, :] = block.T.reshape(total, r1 - r0, w).to(storage_dtype)

    if ev.geometry is not None:  # later per-uv evaluations (training targets) read level 0's grid
        ev.geometry.resolution = (h, w)
    channels, o = [], 0
    for name, width, mx_type in plan:
        if mx_type == "lean":
            ch = Channel(name, 5, "lean_moments", "lean", "slope moments (sx, sy, Mxx, Myy, Mxy)")
        else:
            sem, filt, unit = _semantic(name, mx_type)
            ch = Channel(name, width, sem, filt, unit)
        ch.range = (float(lo[o:o + width].min()), float(hi[o:o + width].max()))
        channels.append(ch)
        o += width
    levels = [level0]
    while levels[-1].shape[1] > 1 or levels[-1].shape[2] > 1:
        prev = levels[-1]  # pooled channel by channel: a float32 copy of one channel at a time
        levels.append(torch.cat([
            F.avg_pool2d(prev[c:c + 1][None].float(), 2, ceil_mode=True, count_include_pad=False)[0].to(storage_dtype)
            for c in range(prev.shape[0])], 0))
    return ParameterStack(channels, levels, constants, lean, notes, ratio)
