"""Directional albedo over a MIP level's footprint: the reference's and a model's estimators.

The directional albedo a(wi) = integral of f(wi, wo) cos(wo) dwo over the hemisphere (linear RGB, no
units: the share of light reflected when lit from ``wi``). Two estimators, shared by the energy check
(:mod:`mtlx2neural.verify.energy`, after training) and the energy balance
(:mod:`mtlx2neural.train.energy_balance`, during it):

- :func:`reference_footprint_albedo`: the reference's albedo averaged over a level-k footprint, Gaussian
  points around each row's uv with a standard deviation of half a level-k texel, as the training targets
  are (:mod:`mtlx2neural.textures.footprint`). The albedo is linear in the BRDF, so this is the albedo of
  the footprint-filtered reference that level k is trained on. Each point's albedo comes from
  scrambled-Sobol directions drawn by the reference's own analytic sampler.
- :func:`mixture_albedo`: a model's albedo, from directions drawn from a mixture of three samplers (the
  model's learned one, the reference's, the cosine-weighted hemisphere) weighed by the mixture's density.
  The model's own sampler alone cannot see energy it does not sample (a near-mirror model with a sharp
  spike where its sampler rarely goes measured 1.1x its reference that way, and rendered 2.2x as bright).

Directions are in the local shading frame, z the normal, ``wi`` towards the viewer.
"""

from __future__ import annotations

import math

import torch

from mtlx2neural.contract import ShadingPoint
from mtlx2neural.reference.vec import cosine_sample
from mtlx2neural.textures.footprint import (
    covered_mean,
    footprint_sigma,
    stratified_gaussian,
)


def view_directions(n: int, degrees, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """``wi`` [n * V, 3] (V view angles per row, random azimuth; local frame, z the normal) and the
    angle of each row in degrees [n * V]."""
    theta = torch.tensor([math.radians(d) for d in degrees]).repeat(n)
    phi = torch.rand(theta.shape[0], generator=generator) * 2 * math.pi
    s = torch.sin(theta)
    wi = torch.stack([s * torch.cos(phi), s * torch.sin(phi), torch.cos(theta)], -1)
    return wi, torch.tensor(list(degrees)).repeat(n)


def probe_rows(texels: int, degrees, generator: torch.Generator, coverage=None
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(uv [n, 2], wi [n, 3], angle [n])`` with n = ``texels`` * V: ``texels`` random uv in [0, 1)^2, each
    with one ``wi`` per view angle of ``degrees`` (:func:`view_directions`). With ``coverage(uv) -> [M]`` (a
    cut-out's) uv are redrawn, up to 8 times, where it is 0, so the rows lie on surface that is there."""
    uv = torch.rand(texels, 2, generator=generator)
    for _ in range(8 if coverage is not None else 0):
        empty = torch.nonzero(coverage(uv) <= 0)[:, 0]
        if len(empty) == 0:
            break
        uv[empty] = torch.rand(len(empty), 2, generator=generator)
    wi, angle = view_directions(texels, degrees, generator)
    return uv.repeat_interleave(len(degrees), 0), wi, angle


def reference_footprint_albedo(reference, wi: torch.Tensor, uv: torch.Tensor, level: int,
                               resolution: tuple[int, int], *, points: int, samples: int, seed: int,
                               generator: torch.Generator, params_at=None, coverage=None,
                               device="cpu") -> torch.Tensor:
    """[N, 3] the reference's directional albedo at ``wi`` [N, 3] averaged over the level-``level``
    footprints around ``uv`` [N, 2] on a finest grid of ``resolution`` (H, W) texels: ``points`` Gaussian
    points per row (a Latin hypercube drawn from ``generator``), ``samples`` Sobol directions each (Sobol
    seed ``seed``). ``params_at(uv [M, 2]) -> {name: [M, width]}`` gives the reference's parameters at
    points (the parameter stack's level 0 when it holds the textures at their own resolution); None
    evaluates the graph there. ``coverage(uv [M, 2]) -> [M]`` (a cut-out's) weighs the points, so a
    footprint averages the surface that is there; a row none of whose points has surface keeps the plain
    mean, as the training's targets do (:func:`~mtlx2neural.textures.footprint.footprint_targets`): with a
    weighted 0 instead, a coarse level's rows whose few points all missed a leaf's outline read the model 6 %
    too bright against the check. No gradients."""
    n = wi.shape[0]
    offsets = stratified_gaussian(n, points, generator) * footprint_sigma(level, resolution)
    pts = (uv[:, None, :] + offsets).reshape(-1, 2).to(device)
    at = ShadingPoint(params=params_at(pts)) if params_at is not None else ShadingPoint(uv=pts)
    with torch.no_grad():
        ref = reference.albedo(wi.to(device).repeat_interleave(points, 0), at, samples=samples, seed=seed)
        if coverage is None:
            return ref.view(n, points, 3).mean(1)
        ref = ref.view(n, points, 3)
        w = coverage(pts.cpu()).to(ref.dtype).to(ref.device).view(n, points, 1)
        return covered_mean((ref * w).sum(1), w.sum(1)[:, 0], ref.mean(1))


def model_level_albedo(model, reference, wi: torch.Tensor, uv: torch.Tensor, level, *, samples: int,
                       seed: int, params_at=None, device="cpu", grad: bool = False) -> torch.Tensor:
    """[N, 3] ``model``'s directional albedo at ``wi`` [N, 3], read at ``uv`` [N, 2] and MIP level ``level``
    (an int, or an [N] tensor of one level per row, so that one call covers every level)
    (:func:`mixture_albedo`, ``samples`` directions per row; the reference's sampler at the rows' centres,
    through ``params_at`` as in :func:`reference_footprint_albedo`). ``grad``: as :func:`mixture_albedo`'s."""
    n = wi.shape[0]
    wi, uv = wi.to(device), uv.to(device)
    centre = ShadingPoint(params=params_at(uv)) if params_at is not None else ShadingPoint(uv=uv)
    lod = (level.to(device=device, dtype=torch.float32) if isinstance(level, torch.Tensor)
           else torch.full((n,), float(level), device=device))
    at = ShadingPoint(uv=uv, lod=lod)
    return mixture_albedo(model, reference, wi, at, centre, samples=samples, seed=seed, grad=grad)


ROW_SHIFT_SEED_OFFSET = 10007
"""The per-row shifts of :func:`row_shifted_sobol` come from a generator seeded with the estimate's seed plus this."""


def row_shifted_sobol(rows: int, samples: int, dims: int, seed: int, device=None, dtype=torch.float32) -> torch.Tensor:
    """``[rows * samples, dims]`` in [0, 1): ``samples`` scrambled Sobol points (seed ``seed``), shifted modulo 1
    by a uniform random vector of each row's own (a Cranley-Patterson rotation, drawn on the CPU). Each row keeps
    the points' even spread; the rows' errors are no longer one shared error, so a sum over many rows (an energy
    ratio) averages them out. With one unshifted sequence for every row, one model's energy check read 0.942 /
    0.941 / 0.927 at seeds 0 / 1 / 2 (docs/history/fast-schedule-2026-12-07.md)."""
    sobol = torch.quasirandom.SobolEngine(dims, scramble=True, seed=seed).draw(samples)
    shift = torch.rand(rows, 1, dims, generator=torch.Generator().manual_seed(seed + ROW_SHIFT_SEED_OFFSET))
    return torch.frac(sobol[None] + shift).reshape(rows * samples, dims).to(device=device, dtype=dtype)


def mixture_albedo(model, reference, wi: torch.Tensor, at, reference_at, samples: int = 256,
                   seed: int = 0, grad: bool = False) -> torch.Tensor:
    """Directional albedo ``[N, 3]`` of ``model`` at unit ``wi`` ``[N, 3]`` (local frame, towards the viewer;
    cosine included), estimated with directions drawn from a mixture of three samplers: ``model``'s own
    at ``at``, ``reference``'s at ``reference_at`` (the same rows, the reference's parameters) and the
    cosine-weighted hemisphere, ``samples`` scrambled-Sobol points per row of which sample j uses
    strategy j mod 3, shifted per row (:func:`row_shifted_sobol`). Each direction is weighed by the mixture's
    density (the three pdfs, each weighed by its strategy's share of the ``samples``: the balance heuristic), so
    the estimate is unbiased wherever the cosine is positive, however poorly the model's sampler matches its
    BRDF, and for any ``samples`` (with equal weights, 32 samples split 11 / 11 / 10 read a near mirror 2-3 %
    high). A failed draw contributes 0. No gradients, unless ``grad``: the model's BRDF values then keep their
    graph (the directions and the mixture's density do not), so the estimate's gradient is the exact gradient of
    the same quadrature with its directions held fixed (what the energy calibration steps along)."""
    n = wi.shape[0]
    rep = wi.repeat_interleave(samples, 0)
    point, ref_point = at.repeat_rows(samples, n), reference_at.repeat_rows(samples, n)
    u = row_shifted_sobol(n, samples, 3, seed, device=wi.device, dtype=wi.dtype)
    per_row = torch.arange(samples, device=wi.device) % 3  # the strategy of each of a row's samples
    strategy = per_row.repeat(n)
    with torch.no_grad():
        wo = cosine_sample(u[:, :2])
        for who, at_rows, k in ((model, point, 0), (reference, ref_point, 1)):  # each samples its third
            rows = torch.nonzero(strategy == k)[:, 0]
            # the direction alone: a model that can draw it without evaluating its BRDF does so
            draw = getattr(who, "sample_direction", None) or who.sample
            wo[rows] = draw(rep[rows], u[rows], at_rows.select(rows, rep.shape[0]))[0].to(wo.dtype)
        share = torch.bincount(per_row, minlength=3).to(wo.dtype) / samples
        density = (share[0] * model.pdf(rep, wo, point) + share[1] * reference.pdf(rep, wo, ref_point)
                   + share[2] * wo[:, 2].clamp(min=0.0) / math.pi)
    with torch.set_grad_enabled(grad):
        f = model.eval(rep, wo, point)
        weight = torch.where((density > 0)[:, None], f / density.clamp(min=1e-30)[:, None], torch.zeros_like(f))
        return weight.view(n, samples, 3).mean(1)
