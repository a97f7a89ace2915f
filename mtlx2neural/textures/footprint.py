"""Footprint-filtered training targets: the reference BRDF averaged over a pixel's footprint.

A query is (uv, MIP level k, wi, wo). Its target is the mean of the reference
``eval`` over points drawn (stratified, :func:`stratified_gaussian`) from an
isotropic Gaussian around ``uv`` whose
standard deviation is half a level-k texel (``2^k`` level-0 texels wide), with
the unfiltered material at each point. The number of points grows with the
filter area in native texels, capped at ``max_samples``.

"Unfiltered" means the stack's level 0 when it is at the textures' own
resolution. When the grid was capped below it (``stack.texel_ratio > 1``), level
0 is itself a LEAN/box-filtered version, whose appearance differs from the true
average (LEAN cannot model masking between the bumps of a normal map, nor
sparkle), so the points evaluate the material graph directly at their uv.

Levels are drawn from a truncated exponential distribution that favours fine
levels: P(k) proportional to exp(-rate * k).

Everything is batched: queries are grouped by level, and each level's points
are evaluated in one call.
"""

from __future__ import annotations

import math

import torch

from mtlx2neural.contract import ShadingPoint
from mtlx2neural.textures.parameter_stack import ParameterStack

SIGMA_TEXELS = 0.5  # the footprint's standard deviation, in level-k texels


def sample_levels(n: int, num_levels: int, rate: float = 1.0, generator: torch.Generator | None = None,
                  device="cpu") -> torch.Tensor:
    """``n`` MIP levels in [0, num_levels) with P(k) ~ exp(-rate k) (int64)."""
    k = torch.arange(num_levels, dtype=torch.float64)
    p = torch.exp(-rate * k)
    return torch.multinomial((p / p.sum()).float(), n, replacement=True, generator=generator).to(device)


def samples_for_level(level: int, max_samples: int, texel_ratio: tuple[float, float] = (1.0, 1.0)) -> int:
    """Points averaged at ``level``: proportional to the filter area in native texels
    (4^k times the native texels per level-0 texel), at least 1, capped."""
    return int(min(max_samples, math.ceil(4 ** level * texel_ratio[0] * texel_ratio[1] - 1e-6)))


def footprint_sigma(level: int, resolution: tuple[int, int], dtype=torch.float32, device=None) -> torch.Tensor:
    """[2] standard deviation in uv (u, v) of a level-``level`` footprint on a grid of ``resolution`` (H, W)
    finest-level texels: :data:`SIGMA_TEXELS` level-k texels per axis."""
    h, w = resolution
    return torch.tensor([SIGMA_TEXELS * 2 ** level / w, SIGMA_TEXELS * 2 ** level / h], dtype=dtype, device=device)


def footprint_targets(reference, stack: ParameterStack, wi: torch.Tensor, wo: torch.Tensor, uv: torch.Tensor,
                      level: torch.Tensor, max_samples: int = 64,
                      generator: torch.Generator | None = None, point_eval=None,
                      one_call: bool = False, weight=None) -> torch.Tensor:
    """Footprint-averaged reference values [N,3] (f * cos, linear RGB) for each query.

    ``reference`` is a :class:`~mtlx2neural.reference.ReferenceMaterial` of the same
    compiled material as ``stack``; ``level`` [N] holds integer MIP levels. Each point is a
    :class:`~mtlx2neural.contract.ShadingPoint`: the stack's level-0 ``params`` at its uv when the
    stack is at the textures' resolution, else its ``uv`` (the graph itself). ``point_eval(wi, wo,
    at)`` replaces ``reference.eval`` at each point (the trainer passes its cone-mollified value,
    :func:`mtlx2neural.train.mollify.cone_mean`).

    ``one_call``: the points of every level go to ``point_eval`` in one batch instead of one call per
    level (the same estimator and the same offsets; the random numbers ``point_eval`` draws come in
    another order). The reference costs a few thousand tensor operations per call whatever its batch,
    so one call instead of one per level (9 on a 256² grid) takes about half the time (BENCHMARKS.md,
    "Time to quality").

    ``weight(points [M, 2]) -> [M]`` (with ``one_call``): the points' mean is weighted by it, e.g. a
    cut-out's coverage, so a footprint averages the surface that is there; a row whose weights sum to 0
    keeps the plain mean.
    """
    point_eval = reference.eval if point_eval is None else point_eval
    n = wi.shape[0]
    h, w = stack.resolution
    native = stack.texel_ratio == (1.0, 1.0)
    out = torch.zeros(n, 3, dtype=wi.dtype, device=wi.device)
    groups = []  # (rows [m], points per row s, points [m*s, 2])
    for k in torch.unique(level).tolist():
        idx = torch.nonzero(level == k)[:, 0]
        s = samples_for_level(int(k), max_samples, stack.texel_ratio)
        m = idx.shape[0]
        # Gaussian offsets in uv: sigma = half a level-k texel, per axis.
        sigma = footprint_sigma(int(k), (h, w), uv.dtype, uv.device)
        offsets = stratified_gaussian(m, s, generator).to(uv.dtype).to(uv.device) * sigma
        pts = (uv[idx, None, :] + offsets).reshape(-1, 2)
        if one_call:
            groups.append((idx, s, pts))
            continue
        wi_k, wo_k = wi[idx].repeat_interleave(s, 0), wo[idx].repeat_interleave(s, 0)
        at = ShadingPoint(params=stack.sample(pts, 0)) if native else ShadingPoint(uv=pts)
        vals = point_eval(wi_k, wo_k, at)
        out[idx] = vals.view(m, s, 3).mean(1)
    if groups:
        rows = torch.cat([idx.repeat_interleave(s) for idx, s, _ in groups])
        pts = torch.cat([p for _, _, p in groups])
        at = ShadingPoint(params=stack.sample(pts, 0)) if native else ShadingPoint(uv=pts)
        vals = point_eval(wi[rows], wo[rows], at).to(out.dtype)
        counts = torch.zeros(n, dtype=wi.dtype, device=wi.device)
        counts.index_add_(0, rows, torch.ones_like(rows, dtype=wi.dtype))
        out.index_add_(0, rows, vals)
        out = out / counts.clamp_min(1.0)[:, None]
        if weight is not None:
            w = weight(pts).to(out.dtype)
            wsum = torch.zeros(n, dtype=out.dtype, device=out.device).index_add_(0, rows, w)
            out = covered_mean(torch.zeros_like(out).index_add_(0, rows, vals * w[:, None]), wsum, out)
    return out


EMPTY_WEIGHT = 1e-6
"""A footprint whose points' weights (a cut-out's coverage) sum to no more than this has no surface."""


def covered_mean(weighted_sum: torch.Tensor, weight_sum: torch.Tensor, plain: torch.Tensor) -> torch.Tensor:
    """[n, 3] each row's weighted mean (``weighted_sum`` [n, 3] over ``weight_sum`` [n]), or its ``plain`` mean
    [n, 3] where the weights sum to no more than :data:`EMPTY_WEIGHT` (a footprint without surface): the rule the
    training targets and the energy estimators share."""
    mean = weighted_sum / weight_sum.clamp_min(1e-12)[:, None]
    return torch.where((weight_sum > EMPTY_WEIGHT)[:, None], mean, plain)


def stratified_gaussian(m: int, s: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """[m, s, 2] standard normal points, a Latin hypercube per row: along each axis the ``s``
    points fall one in each of ``s`` equal-probability strata (jittered within it, the strata
    shuffled independently per axis), mapped through the inverse normal CDF.

    Each point is still N(0, I) and the row mean still an unbiased estimate of a footprint
    average, with less variance than ``s`` independent draws: a normal map's crease seen by 16
    points (the GlazedCeramic's grout) gives a target half as noisy (log-L1 to a 256-point
    average 0.053 instead of 0.13; docs/history/BENCHMARKS-2026-12-01.md)."""
    perm = torch.argsort(torch.rand(m, s, 2, generator=generator), dim=1)
    u = (perm + torch.rand(m, s, 2, generator=generator)) / s
    return torch.special.ndtri(u.clamp(1e-7, 1 - 1e-7))
