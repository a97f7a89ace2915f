"""Energy check: does a trained model keep the reference's directional albedo at every MIP level?

The directional albedo a(wi) = integral of f(wi, wo) cos(wo) dwo over the hemisphere is the share of
light a surface reflects when lit from ``wi``; a model darker than its reference loses it. Sharp
lobes (near-mirror metals, clear coats) are where a median-seeking loss drops it first, and a
per-pixel image metric may not notice (a black sphere under a directional light can still score a
moderate HDR FLIP).

For each MIP level k of the model's latent pyramid, :func:`energy_check` draws ``texels`` random uv
and, for each, one ``wi`` per view angle (``view_degrees``, from the normal; random azimuth), and
compares

- the model's albedo at (uv, lod = k): ``Material.albedo`` over its own sampler, and
- the reference's albedo averaged over the level's footprint: ``footprint_points`` Gaussian points
  around uv with a standard deviation of half a level-k texel, as the training targets are
  (:mod:`mtlx2neural.textures.footprint`); the albedo is linear in the BRDF, so this is the albedo of
  the footprint-filtered reference that level k was trained on.

The level's **energy ratio** is sum(luminance of the model's albedo) / sum(luminance of the
reference's) over all its rows: 1 keeps the energy, 0.5 loses half. Sums, not a mean of per-row
ratios, so that a dark texel cannot dominate. Luminance weights are Rec. 709's (``reference.vec.luminance``). A uniform material has
one level (1x1) and the reference's points all coincide.

Monte Carlo: the reference's albedo is estimated with ``samples`` scrambled-Sobol directions per
point by its own analytic sampler. The model's is **not** estimated by its learned sampler alone,
which cannot see energy it does not sample (a near-mirror model with a sharp spike where its sampler
rarely goes measured 1.1x its reference that way, and rendered 2.2x as bright):
:func:`~mtlx2neural.textures.footprint_albedo.mixture_albedo`
draws a third of the directions from each of the model's sampler, the reference's sampler at the row's
uv and the cosine-weighted hemisphere, and weighs them by the mixture's density (the balance
heuristic), which is unbiased wherever the cosine is positive. Its directions are one Sobol sequence
shifted per row (:func:`~mtlx2neural.textures.footprint_albedo.row_shifted_sobol`), so the rows' errors
average out in the level's sum: with one shared sequence a textured BrushedMetal model read 0.942 / 0.941 /
0.927 at seeds 0 / 1 / 2, with the shifts 0.953 / 0.947 / 0.947. With the defaults a ratio is good to
about 1-2 % for rough lobes and about 5 % for a near-mirror one, mostly from which texels are drawn where the
model's energy varies from texel to texel: one model of the scene sample's gold read 0.954-0.965 at its lowest level
over three seeds with 64 texels, 0.965-0.986 with 256 (at 5x the time; docs/history/energy-calibration-2026-12-08.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from mtlx2neural.reference.vec import luminance
from mtlx2neural.textures.footprint_albedo import (
    model_level_albedo,
    probe_rows,
    reference_footprint_albedo,
)

VIEW_DEGREES = (0.0, 30.0, 60.0, 80.0)
"""Default view angles from the normal, degrees."""


@dataclass
class LevelEnergy:
    """One MIP level: ``ratio`` (model / reference, summed luminance of the directional albedo),
    ``reference`` and ``model`` (mean luminance albedo over the rows, in [0, 1] for an energy-conserving
    material), and ``ratio_by_view`` ({view angle in degrees: ratio})."""

    level: int
    ratio: float
    reference: float
    model: float
    ratio_by_view: dict[float, float] = field(default_factory=dict)


@dataclass
class EnergyCheck:
    """The energy ratio of every MIP level (finest first) and the settings it was measured with."""

    levels: list[LevelEnergy]
    texels: int
    samples: int
    footprint_points: int
    view_degrees: tuple[float, ...]

    @property
    def min_ratio(self) -> float:
        """The lowest level ratio (levels whose reference albedo is black are left out: nothing to keep)."""
        kept = [lv.ratio for lv in self.levels if math.isfinite(lv.ratio)]
        return min(kept) if kept else float("nan")

    @property
    def max_ratio(self) -> float:
        """The highest level ratio (a model brighter than its reference)."""
        kept = [lv.ratio for lv in self.levels if math.isfinite(lv.ratio)]
        return max(kept) if kept else float("nan")

    @property
    def by_view(self) -> dict[float, float]:
        """{view angle in degrees: that view's ratio averaged over the levels} (levels without a ratio left
        out). The level ratios pool every view, so a model too dark at the normal and too bright at grazing
        can keep a level ratio near 1: this shows which way each view goes (the textured GlazedCeramic with
        ``fast``: 0.89-0.96 up to 60 degrees, 0.96-1.21 at 80; docs/history/energy-levers-2026-12-06.md)."""
        out = {}
        for d in self.view_degrees:
            vals = [lv.ratio_by_view.get(d, float("nan")) for lv in self.levels]
            vals = [v for v in vals if math.isfinite(v)]
            out[d] = sum(vals) / len(vals) if vals else float("nan")
        return out

    @property
    def brightest_level(self) -> int | None:
        kept = [lv for lv in self.levels if math.isfinite(lv.ratio)]
        return max(kept, key=lambda lv: lv.ratio).level if kept else None

    @property
    def worst_level(self) -> int | None:
        kept = [lv for lv in self.levels if math.isfinite(lv.ratio)]
        return min(kept, key=lambda lv: lv.ratio).level if kept else None

    def to_json(self) -> dict:
        """``{"min_ratio", "max_ratio", "by_level": [ratio per level], "reference_by_level",
        "model_by_level", "by_view": [ratio per view angle, as ``view_degrees``, averaged over the levels:
        :attr:`by_view`], "texels", "samples", "view_degrees"}``."""
        return {"min_ratio": self.min_ratio, "max_ratio": self.max_ratio, "by_level": [lv.ratio for lv in self.levels],
                "by_view": list(self.by_view.values()),
                "reference_by_level": [lv.reference for lv in self.levels],
                "model_by_level": [lv.model for lv in self.levels],
                "texels": self.texels, "samples": self.samples, "view_degrees": list(self.view_degrees)}


def energy_check(reference, model, resolution: tuple[int, int], levels: int, *, texels: int = 64,
                 samples: int = 64, footprint_points: int = 8, view_degrees=VIEW_DEGREES, seed: int = 0,
                 params_at=None, device="cpu", coverage=None) -> EnergyCheck:
    """The energy ratio per MIP level of ``model`` against ``reference`` (module docstring).

    ``resolution``: the finest latent grid (H, W) in texels, which sets the footprints' size;
    ``levels``: how many MIP levels to check (finest first). ``params_at``: optional ``uv [M, 2] ->
    {name: [M, width]}`` giving the reference's parameters at points (the parameter stack's level 0
    when it holds the textures at their own resolution, as the training does); None evaluates the
    reference's graph at the points. ``device``: where the materials live (the draws are made on the
    CPU, so the figures do not depend on it). Runs without gradients; seeded by ``seed``.
    ``coverage(uv [M, 2]) -> [M]`` (a cut-out's, in [0, 1]): texels are drawn where it is positive and the
    reference's footprint points are weighted by it, as training weights them, so the empty part of a
    cut-out (whose look no consumer shows) does not count."""
    g = torch.Generator().manual_seed(seed)
    out = []
    for k in range(levels):
        uv_rows, wi, angle = probe_rows(texels, view_degrees, g, coverage)
        ref = reference_footprint_albedo(reference, wi, uv_rows, k, resolution, points=footprint_points,
                                         samples=samples, seed=seed, generator=g, params_at=params_at,
                                         coverage=coverage, device=device)
        mod = model_level_albedo(model, reference, wi, uv_rows, k, samples=samples * footprint_points, seed=seed,
                                 params_at=params_at, device=device)
        ref_l, mod_l = luminance(ref.float().cpu()), luminance(mod.float().cpu())
        by_view = {}
        for d in view_degrees:
            sel = angle == d
            r = float(ref_l[sel].sum())
            by_view[float(d)] = float(mod_l[sel].sum()) / r if r > 0 else float("nan")
        total = float(ref_l.sum())
        out.append(LevelEnergy(k, float(mod_l.sum()) / total if total > 0 else float("nan"),
                               float(ref_l.mean()), float(mod_l.mean()), by_view))
    return EnergyCheck(out, texels, samples, footprint_points, tuple(float(d) for d in view_degrees))
