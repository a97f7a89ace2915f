"""Emission and opacity maps beside the latent pyramid, prefiltered for every level of detail.

:func:`build_surface_maps` evaluates a compiled material's emission and opacity
(:mod:`mtlx2neural.graph.surface_terms`) at the texel centres of the latent grid (``s x s`` sub-texel
samples per texel when the grid is coarser than the textures) and builds a pyramid for each, with the
latent pyramid's level count and halving (rounding up), so one ``lod`` reads all three:

- **Opacity** has one of three modes. ``opaque``: no map. ``mask`` (every sample is 0 or 1: a cut-out,
  whose shading model thresholded it): the consumer alpha-tests the map at :data:`ALPHA_CUTOFF`. Level
  0 holds the box average of the samples, so its bilinear lookup tested at 0.5 puts an edge within half
  a texel of the original; a coarser level is the box-filtered coverage scaled so that the share of its
  texels passing the test equals level 0's (coverage-preserving MIPs, after Castano's alpha-to-coverage
  fix), so a fern neither vanishes nor thickens at distance. ``blend``: a fraction, box-filtered, used
  as it is. A constant needs no texture (``opacity_constant``).
- **Emission** (radiance, linear working-space RGB, no cosine) is box-filtered *weighted by coverage*:
  a texel's value is the mean over the surface that is there, so the empty part of a cut-out does not
  darken (or tint) the emitters at its edge. A constant needs no texture (``emission_constant``).

``coverage_levels[k]`` [H_k, W_k] is the plain box-filtered coverage of each level (0 where no surface
is): training draws uv only where level 0 has surface and :func:`dilate` fills the latents of empty
texels from their neighbours. Maps are ``[C, H, W]`` float32, row 0 at the top of UV space (v = 1), and
wrap periodically, as the latents do.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import torch
import torch.nn.functional as F

from mtlx2neural.contract import as_point
from mtlx2neural.errors import InputError
from mtlx2neural.graph.compile import CompiledMaterial
from mtlx2neural.graph.surface_terms import constant_terms, evaluate
from mtlx2neural.imaging.grid_lookup import bilinear_periodic

ALPHA_CUTOFF = 0.5
"""The alpha test of a ``mask`` opacity map: covered where the map is >= 0.5."""
MAX_SUBSAMPLES = 4
"""Sub-texel samples per axis at most when the latent grid is coarser than the textures."""
BINARY_TOLERANCE = 1e-4


def _pool(x: torch.Tensor) -> torch.Tensor:
    return F.avg_pool2d(x[None], 2, ceil_mode=True, count_include_pad=False)[0]


def level_shapes(h: int, w: int) -> list[tuple[int, int]]:
    """(H, W) of every level from (h, w) down to 1x1, halving and rounding up (the latent pyramid's)."""
    shapes = [(h, w)]
    while shapes[-1] != (1, 1):
        a, b = shapes[-1]
        shapes.append(((a + 1) // 2, (b + 1) // 2))
    return shapes


def used_opacity(value: float, alpha_mode: str) -> float:
    """A constant opacity as a consumer uses it: a ``mask``'s alpha-tested at :data:`ALPHA_CUTOFF` (0 or 1),
    otherwise clamped to [0, 1] (what :func:`mtlx2neural.contract.coverage_of` does per point)."""
    if alpha_mode == "mask":
        return float(value >= ALPHA_CUTOFF)
    return min(max(float(value), 0.0), 1.0)


def coverage_preserving(level0: torch.Tensor, count: int, cutoff: float = ALPHA_CUTOFF) -> list[torch.Tensor]:
    """``count`` levels of a mask's opacity [1, H, W] (level 0 as given): each coarser level is the box
    average of the previous *unscaled* level (plus half its 3x3 mean, to break ties), scaled so that the
    share of its texels at or above ``cutoff`` is as near level 0's as the values allow."""
    target = float((level0 >= cutoff).float().mean())
    levels, plain = [level0], level0
    for _ in range(count - 1):
        plain = _pool(plain)
        if target <= 0.0 or target >= 1.0 or plain.max() <= 0:
            levels.append((plain >= cutoff).float() if target <= 0.0 else torch.ones_like(plain))
            continue
        # Box averages of a binary map take few distinct values (a one-texel strand is 0.5 everywhere at
        # the next level), so texels tie; half the 3x3 neighbourhood's mean ranks texels within a tie, so
        # the share passing the test can follow level 0's closely.
        rank = plain + 0.5 * F.avg_pool2d(F.pad(plain[None], (1, 1, 1, 1), mode="circular"), 3, 1)[0]
        flat = rank.flatten()
        # The cutoff moves to the value whose share of texels at or above it is nearest level 0's share.
        values, counts = torch.unique(flat[flat > 0], return_counts=True)
        at_or_above = counts.flip(0).cumsum(0).flip(0).float() / flat.numel()
        tau = float(values[torch.argmin((at_or_above - target).abs())])
        # Just above the cutoff (1 + 2^-10 survives FP16), so a bilinear read between two passing texels
        # cannot round below it.
        levels.append((rank * (cutoff * (1.0 + 2.0 ** -10) / max(tau, 1e-6))).clamp(0.0, 1.0))
    return levels


@dataclass
class SurfaceMaps:
    """A material's emission and opacity for every level (module docstring). Lookups follow the
    :class:`~mtlx2neural.contract.Material` conventions: ``at`` a ShadingPoint (uv, lod in levels,
    u_level choosing between the two nearest levels, as the latents do) or a [N, 2] uv tensor."""

    emission_levels: list[torch.Tensor] | None = None
    emission_constant: tuple[float, float, float] | None = None
    opacity_levels: list[torch.Tensor] | None = None
    opacity_constant: float | None = None
    alpha_mode: str = "opaque"
    """``opaque``, ``mask`` (alpha-tested at :data:`ALPHA_CUTOFF`) or ``blend``."""
    coverage_levels: list[torch.Tensor] = field(default_factory=list)
    coverage: float = 1.0
    """Share of level 0's texels that are covered (after the alpha test of a mask)."""

    @property
    def alpha_cutoff(self) -> float | None:
        return ALPHA_CUTOFF if self.alpha_mode == "mask" else None

    @property
    def emits(self) -> bool:
        return self.emission_levels is not None or self.emission_constant is not None

    @property
    def partial(self) -> bool:
        """Whether some of level 0 has no surface (a cut-out or a blend below 1, with its coverage levels):
        training, the energy check and the held-out error then look only where there is surface."""
        return bool(self.coverage_levels) and self.coverage < 1

    @property
    def empty(self) -> bool:
        """Nothing to export: no emission and opaque."""
        return not self.emits and self.alpha_mode == "opaque"

    def _levels(self, levels: list[torch.Tensor], at) -> torch.Tensor:
        p = as_point(at)
        uv = p.uv if p.uv is not None else torch.zeros(1, 2)
        n = uv.shape[0]
        lod = p.lod if p.lod is not None else torch.zeros(n)
        u = p.u_level if p.u_level is not None else torch.zeros(n)
        last = len(levels) - 1
        lod = lod.to(torch.float32).clamp(0.0, last)
        k = lod.floor()
        k = (k + (u.to(torch.float32) < (lod - k)).float()).clamp(0, last).long()
        out = torch.zeros(n, levels[0].shape[0], dtype=torch.float32, device=uv.device)
        for level in torch.unique(k).tolist():
            idx = torch.nonzero(k == level)[:, 0]
            out[idx] = bilinear_periodic(levels[int(level)].to(uv.device), uv[idx].to(torch.float32))
        return out

    def _rows(self, at) -> int:
        p = as_point(at)
        return 1 if p.uv is None else p.uv.shape[0]

    def emission(self, at=None) -> torch.Tensor | None:
        """Emitted radiance [N, 3] (linear RGB, no cosine) at ``at``; None when nothing is emitted."""
        if self.emission_levels is not None:
            return self._levels(self.emission_levels, at)
        if self.emission_constant is not None:
            return torch.tensor([self.emission_constant], dtype=torch.float32).expand(self._rows(at), 3)
        return None

    def opacity(self, at=None) -> torch.Tensor | None:
        """The opacity map [N] at ``at`` (a mask's is alpha-tested by the consumer at :attr:`alpha_cutoff`:
        :func:`mtlx2neural.contract.coverage_of`); None when opaque."""
        if self.opacity_levels is not None:
            return self._levels(self.opacity_levels, at)[:, 0]
        if self.opacity_constant is not None:
            return torch.full((self._rows(at),), float(self.opacity_constant))
        return None

    def coverage_at(self, uv: torch.Tensor) -> torch.Tensor:
        """[N] level-0 coverage (bilinear, the plain box average of the surface that is there) at ``uv``."""
        if not self.coverage_levels:
            return torch.ones(uv.shape[0], dtype=torch.float32, device=uv.device)
        return bilinear_periodic(self.coverage_levels[0][None].to(uv.device), uv.float())[:, 0]

    def texel_covered(self, uv: torch.Tensor) -> torch.Tensor:
        """[N] bool: whether the level-0 texel under each uv holds any surface (coverage > 0)."""
        if not self.coverage_levels:
            return torch.ones(uv.shape[0], dtype=torch.bool, device=uv.device)
        cov = self.coverage_levels[0]
        h, w = cov.shape
        col = (torch.remainder(uv[:, 0], 1.0) * w).long().clamp(0, w - 1)
        row = ((1.0 - torch.remainder(uv[:, 1], 1.0)) * h).long().clamp(0, h - 1)
        return cov.to(uv.device)[row, col] > 0

    def describe(self) -> dict:
        """JSON summary: emission (none/constant/texture), opacity mode and coverage."""
        return {"emission": "texture" if self.emission_levels is not None else
                ("constant" if self.emission_constant is not None else "none"),
                "alpha_mode": self.alpha_mode, "alpha_cutoff": self.alpha_cutoff,
                "opacity": "texture" if self.opacity_levels is not None else
                ("constant" if self.opacity_constant is not None else "none"),
                "coverage": round(self.coverage, 4)}

    def state(self) -> dict:
        """Tensors and settings to save (``torch.save``); :meth:`from_state` rebuilds the maps."""
        return {k: getattr(self, k) for k in ("emission_levels", "emission_constant", "opacity_levels",
                                             "opacity_constant", "alpha_mode", "coverage_levels", "coverage")}

    @classmethod
    def from_state(cls, state: dict) -> SurfaceMaps:
        return cls(**state)


class SurfacesBeside:
    """Emission and opacity for a material whose BRDF is a model (neural, analytic): read from its
    ``surface`` attribute, a :class:`SurfaceMaps` or None (emits nothing, opaque)."""

    surface: SurfaceMaps | None = None

    def emission(self, at=None) -> torch.Tensor | None:
        """Emitted radiance [N,3] (linear RGB, no cosine) from the surface maps, or None (nothing emitted)."""
        return None if self.surface is None else self.surface.emission(at)

    def opacity(self, at=None) -> torch.Tensor | None:
        """The opacity map [N] (alpha-tested at :attr:`alpha_cutoff` for a cut-out), or None (opaque)."""
        return None if self.surface is None else self.surface.opacity(at)

    @property
    def alpha_cutoff(self) -> float | None:
        return None if self.surface is None else self.surface.alpha_cutoff


def build_surface_maps(compiled: CompiledMaterial, resolution: tuple[int, int],
                       texel_ratio: tuple[float, float] = (1.0, 1.0), chunk: int = 1 << 16) -> SurfaceMaps:
    """The emission and opacity maps of ``compiled`` on a ``resolution`` (H, W) grid (the latent grid),
    ``texel_ratio`` native texels per grid texel (rows, columns): up to :data:`MAX_SUBSAMPLES` samples per
    axis are averaged per texel. Constant emission or opacity gives no map (module docstring)."""
    terms, ev = compiled.surface, compiled.evaluator
    maps = SurfaceMaps()
    textured_e = bool(terms.emission) and not constant_terms(ev, terms.emission)
    textured_o = terms.opacity is not None and not constant_terms(ev, terms.opacity)
    if terms.emission and not textured_e:
        maps.emission_constant = tuple(float(x) for x in evaluate(ev, terms.emission, {}, 1, 3)[0])
    if terms.opacity is not None and not textured_o:
        value = float(evaluate(ev, terms.opacity, {}, 1, 1)[0, 0])
        maps.opacity_constant = value
        maps.alpha_mode = "mask" if min(value, 1 - value) < BINARY_TOLERANCE else "blend"
        maps.coverage = used_opacity(value, maps.alpha_mode)
    if not (textured_e or textured_o):
        return maps
    h, w = resolution
    sy, sx = (min(MAX_SUBSAMPLES, max(1, math.ceil(r - 1e-6))) for r in texel_ratio)
    nodes = compiled.surface_nodes
    xs = (torch.arange(w * sx, dtype=torch.float32) + 0.5) / (w * sx)
    ys = 1.0 - (torch.arange(h * sy, dtype=torch.float32) + 0.5) / (h * sy)
    uv = torch.stack([xs[None, :].expand(h * sy, -1), ys[:, None].expand(-1, w * sx)], -1).reshape(-1, 2)
    emission, opacity = [], []
    for r0 in range(0, uv.shape[0], chunk):
        part = uv[r0:r0 + chunk].to(ev.device, ev.dtype)
        env = ev.run(nodes, part)
        if textured_e:
            emission.append(evaluate(ev, terms.emission, env, part.shape[0], 3).float().cpu())
        if textured_o:
            opacity.append(evaluate(ev, terms.opacity, env, part.shape[0], 1).float().clamp(0, 1).cpu())

    def grid(rows: list[torch.Tensor], c: int) -> torch.Tensor:
        """Samples [h*sy*w*sx, c] -> [c, h, w], averaging each texel's sy x sx samples."""
        x = torch.cat(rows).view(h, sy, w, sx, c)
        return x.mean((1, 3)).permute(2, 0, 1).contiguous()

    shapes = level_shapes(h, w)
    cover = torch.ones(1, h, w)
    if textured_o:
        samples = torch.cat(opacity)
        binary = bool(((samples < BINARY_TOLERANCE) | (samples > 1 - BINARY_TOLERANCE)).all())
        alpha0 = grid(opacity, 1)
        maps.alpha_mode = "mask" if binary else "blend"
        maps.opacity_levels = (coverage_preserving(alpha0, len(shapes)) if binary else
                               [alpha0] + _box_levels(alpha0, len(shapes) - 1))
        cover = alpha0
        maps.coverage = float((alpha0 >= ALPHA_CUTOFF).float().mean()) if binary else float(alpha0.mean())
    elif maps.opacity_constant is not None:
        cover = torch.full((1, h, w), maps.coverage)
    maps.coverage_levels = [cover[0]] + [c[0] for c in _box_levels(cover, len(shapes) - 1)]
    if textured_e:
        e0 = grid(emission, 3)
        levels, weighted, weight = [e0], e0 * cover, cover
        for _ in range(len(shapes) - 1):
            weighted, weight, plain = _pool(weighted), _pool(weight), _pool(levels[-1])
            levels.append(torch.where(weight > 1e-6, weighted / weight.clamp_min(1e-6), plain))
        maps.emission_levels = levels
    return maps


def _box_levels(level0: torch.Tensor, count: int) -> list[torch.Tensor]:
    out, x = [], level0
    for _ in range(count):
        x = _pool(x)
        out.append(x)
    return out


def dilate(grid: torch.Tensor, covered: torch.Tensor, max_steps: int | None = None) -> torch.Tensor:
    """``grid`` [C, H, W] with every texel where ``covered`` [H, W] is False replaced by the mean of its
    already-filled 3x3 neighbours, ring by ring outwards (UV wraps), so filtering across a cut-out's edge
    mixes in values like the surface's own instead of untrained ones. Texels no ring reaches keep their
    values. ``max_steps`` rings at most (default: the grid's larger side)."""
    filled = covered.clone().to(grid.device)
    if bool(filled.all()) or not bool(filled.any()):
        return grid
    out = grid.clone()
    kernel = torch.ones(1, 1, 3, 3, dtype=grid.dtype, device=grid.device)
    for _ in range(max_steps or max(grid.shape[1:])):
        f = filled.to(grid.dtype)[None, None]
        pad = (1, 1, 1, 1)
        count = F.conv2d(F.pad(f, pad, mode="circular"), kernel)[0, 0]
        sums = F.conv2d(F.pad((out * filled.to(grid.dtype))[:, None], pad, mode="circular"), kernel)[:, 0]
        grow = (~filled) & (count > 0)
        if not bool(grow.any()):
            break
        out = torch.where(grow[None], sums / count.clamp_min(1)[None], out)
        filled = filled | grow
    return out


MANIFEST_FILE = "surface.json"
"""An export folder's manifest of its emission and opacity maps (:mod:`mtlx2neural.export.surface_files`
writes it; the shader generators and ``load_neural`` read it)."""


def read_surface_manifest(folder) -> dict | None:
    """``surface.json`` of an export folder, or None when the material has no surface maps."""
    path = Path(folder) / MANIFEST_FILE
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot be read as the surface maps' manifest ({exc}); export the material "
                         f"again") from exc


SURFACE_FILE = "surface_maps.pt"
"""The emission and opacity maps in a material's training folder (:meth:`SurfaceMaps.state`)."""


def load_surface_maps(path) -> SurfaceMaps | None:
    """The maps saved at ``path`` (:data:`SURFACE_FILE`), or None when there is no such file (the material
    emits nothing and is opaque, or was trained before maps existed)."""
    p = Path(path)
    if not p.is_file():
        return None
    return SurfaceMaps.from_state(torch.load(p, map_location="cpu", weights_only=False))
