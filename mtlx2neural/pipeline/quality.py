"""The quality gate: which converted materials a scene must not pass off as converted.

After every material of a run is trained, each record is judged on its own terms and against the
run's other materials:

- **energy** (:mod:`mtlx2neural.verify.energy`, ``record.energy``): a MIP level whose neural directional
  albedo is below ``ENERGY_LOW`` (half) of the reference's is a material trained to black or nearly
  so; above ``ENERGY_HIGH`` (twice), one that glows. (The record's softer warnings start at 0.9 and
  1.2: visibly darker or brighter, but a usable model.)
- **FLIP**: mean HDR FLIP of the sphere views (``record.flip_mean``: three lit, one under the sky) above ``FLIP_HIGH`` (0.3: the samples
  that convert well sit at 0.01-0.17, a black or wrong-lobed model at 0.5-1), or above ``FLIP_RELATIVE``
  times the run's median while above ``FLIP_FLOOR`` (0.2; a material far worse than its scene's others).

A flagged material is handled by the run's ``flagged`` policy (``ConvertOptions.flagged``):

- ``original`` (the default): export it, and make the layer select its ``original`` variant, so the
  default render is the original material; the ``neural`` variant stays selectable, and
  ``neural:quality`` says why it is not the default;
- ``neural``: export it and keep the ``neural`` variant selected (the warning still names it);
- ``skip``: do not export it (it keeps its original network, as a material that failed to train),
  exit 3 with the others converted.
"""

from __future__ import annotations

import math
import statistics

ENERGY_LOW = 0.5
"""A MIP level keeping less than this share of the reference's directional albedo flags the material."""
ENERGY_HIGH = 2.0
"""A MIP level reflecting more than this multiple of the reference's directional albedo flags it."""
FLIP_HIGH = 0.3
"""Mean sphere-view HDR FLIP above which a material is flagged whatever its scene."""
FLIP_RELATIVE = 3.0
"""A material whose FLIP exceeds this multiple of the run's median (and ``FLIP_FLOOR``) is flagged."""
FLIP_FLOOR = 0.2
"""Below this FLIP a material is never flagged for being worse than its scene's median (the worst sample
that converts well, the BrushedMetal, is at 0.17 with `fast`)."""
VIEWER_FLIP_HIGH = FLIP_HIGH
"""The record warns (it does not flag: path tracers shade the BRDF, which the gate judges) when the
environment view shaded by the prefiltered path a viewer uses (``record.flip_viewer``) is above this."""
POLICIES = ("original", "neural", "skip")
"""``ConvertOptions.flagged`` choices (module docstring)."""


def viewer_warning(record) -> str | None:
    """The record's warning when its viewer figure (``record.flip_viewer``) is above :data:`VIEWER_FLIP_HIGH`,
    in words, with the same view's figure for the BRDF sampled (the last of ``flip_per_view``; a path tracer's
    figure, which the node's sampled path reaches only with many directions: an unseen velvet in MaterialX's
    renderer measured 0.31 sampled against 0.23 prefiltered at the default 16); else None."""
    flip = record.flip_viewer
    if flip is None or not math.isfinite(flip) or flip <= VIEWER_FLIP_HIGH:
        return None
    sampled = f", against {record.flip_per_view[-1]:.3f} for the BRDF sampled" if record.flip_per_view else ""
    return (f"viewer: the prefiltered environment path (the MaterialX node's default) reaches HDR FLIP {flip:.3f} "
            f"under the sky{sampled}; the node's sampled path (env_prefiltered false) tends to the latter as "
            f"env_samples grows, but is noisy at its default")


def flag_reasons(record, scene_median: float | None) -> list[str]:
    """Why ``record`` (a :class:`~mtlx2neural.material_record.MaterialRecord`) fails the gate, in words;
    empty when it passes. ``scene_median``: the median ``flip_mean`` of the run's materials (None: no
    relative check)."""
    reasons = []
    energy = record.energy or {}
    low, high = energy.get("min_ratio"), energy.get("max_ratio")
    if low is not None and math.isfinite(low) and low < ENERGY_LOW:
        reasons.append(f"keeps {low:.0%} of the reference's directional albedo at its worst MIP level "
                       f"(energy check; under {ENERGY_LOW:.0%}: trained dark or black)")
    if high is not None and math.isfinite(high) and high > ENERGY_HIGH:
        reasons.append(f"reflects {high:.0%} of the reference's directional albedo at its brightest MIP level "
                       f"(energy check; over {ENERGY_HIGH:.0%})")
    flip = record.flip_mean
    if math.isfinite(flip):
        if flip > FLIP_HIGH:
            reasons.append(f"HDR FLIP {flip:.3f} on the sphere views (over {FLIP_HIGH})")
        elif (scene_median is not None and flip > FLIP_FLOOR and flip > FLIP_RELATIVE * scene_median):
            reasons.append(f"HDR FLIP {flip:.3f} on the sphere views, over {FLIP_RELATIVE:g}x the run's median "
                           f"{scene_median:.3f}")
    return reasons


def judge(records) -> dict[str, list[str]]:
    """``{material: reasons}`` for every record of a run that fails the gate (module docstring); the
    relative FLIP check compares with the median over all ``records`` with a finite FLIP."""
    flips = [r.flip_mean for r in records if math.isfinite(r.flip_mean)]
    median = statistics.median(flips) if len(flips) >= 2 else None
    out = {}
    for r in records:
        reasons = flag_reasons(r, median)
        if reasons:
            out[r.material] = reasons
    return out


def verdict(reasons: list[str], policy: str) -> dict:
    """The record's ``quality`` entry: ``flagged``, ``reasons`` and what the layer does (``policy``)."""
    return {"flagged": bool(reasons), "reasons": list(reasons), "policy": policy}
