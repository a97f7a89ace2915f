"""Mollified training targets: the reference BRDF averaged over a cone of outgoing directions.

The mollified value at (wi, wo) is the mean of f*cos over the cone of half-angle ``angle``
around wo::

    m(wi, wo) = 1/Omega * integral over cone(wo) of f(wi, w) * cos(w) dw,   Omega = 2 pi (1 - cos angle)

It keeps a lobe's energy while widening it to at least the cone: a roughness-0.05 clear coat
(GGX alpha 0.0025, about 0.15 degrees wide) becomes a lobe the decoder can represent, instead of
a spike that uniform training directions find in 0.3% of samples and that the median-seeking
log-L1 loss then drops (its grazing albedo of 0.8 came out as 0.16; docs/history/BENCHMARKS-2026-12-01.md).

Estimator (:func:`cone_mean`): stratified multiple importance sampling with ``pairs`` pairs of
directions, one uniform in the cone and one from the reference's own sampler, combined by the
balance heuristic. The reference's sample finds a sharp lobe whenever its core lies inside the
cone, so the estimate has little variance there; the uniform one covers smooth lobes and the
cone's rim. Unbiased for m for any reference (the uniform density covers the whole cone).
"""

from __future__ import annotations

import math

import torch

from mtlx2neural.contract import ShadingPoint, as_point
from mtlx2neural.train.directions import cone_jitter


def cone_mean(reference, wi: torch.Tensor, wo: torch.Tensor, angle: float, pairs: int = 1,
              generator: torch.Generator | None = None, at=None) -> torch.Tensor:
    """Estimate of m(wi, wo) [N,3] (module docstring), f*cos in linear RGB, local frame.

    ``at`` (a :class:`~mtlx2neural.contract.ShadingPoint` with ``uv`` [N,2] or ``params``, per-row
    parameters from :meth:`ParameterStack.sample`; or a [N,2] uv tensor; or ``None``) selects the
    point of a textured material, as for ``reference.eval``. ``angle`` in radians; 0 returns
    ``reference.eval(wi, wo, at)``.
    """
    if angle <= 0:
        return reference.eval(wi, wo, at)
    point = as_point(at)
    uv, params = point.uv, point.params
    compiled = getattr(reference, "compiled", None)  # a measured material has no graph
    if params is None and uv is not None and compiled is not None and compiled.spatial_nodes:
        params, uv = reference.parameters_at(uv), None  # the material graph once, not five times
    n = wi.shape[0]
    omega = 2.0 * math.pi * (1.0 - math.cos(angle))
    cos_max = math.cos(angle)

    def rep(x):
        return None if x is None else x.repeat_interleave(pairs, 0)

    wi_p = rep(wi)
    at_p = ShadingPoint(uv=rep(uv), params=None if params is None else {k: rep(v) for k, v in params.items()})
    w_uniform = cone_jitter(wo, angle, pairs, generator)
    u = torch.rand(n * pairs, 2, generator=generator).to(wi.device)
    if hasattr(reference, "sample_and_eval_pdf"):  # a ReferenceMaterial: both directions from one evaluation
        (w_sampled, f_sampled, p_sampled), (f_uniform, p_uniform) = reference.sample_and_eval_pdf(
            wi_p, u, w_uniform, at_p)

        def value_and_density(w):
            return (f_sampled, p_sampled) if w is w_sampled else (f_uniform, p_uniform)
    else:  # the contract alone: a non-finite sample takes the uniform direction
        w_sampled, _, _ = reference.sample(wi_p, u, at_p)
        w_sampled = torch.where(torch.isfinite(w_sampled).all(-1, keepdim=True), w_sampled, w_uniform)

        def value_and_density(w):
            return reference.eval(wi_p, w, at_p), reference.pdf(wi_p, w, at_p)
    axis = rep(wo)
    total = torch.zeros(n * pairs, 3, dtype=wi.dtype, device=wi.device)
    for w in (w_uniform, w_sampled):
        inside = (w * axis).sum(-1) >= cos_max - 1e-7
        # balance heuristic over one sample of each strategy: f / (p_uniform + p_reference)
        f, pdf = value_and_density(w)
        density = inside.to(wi.dtype) / omega + pdf
        ok = inside & (density > 0)
        total = total + torch.where(ok[:, None], f / density.clamp_min(1e-30)[:, None], torch.zeros_like(f))
    est = total.view(n, pairs, 3).mean(1) / omega
    return torch.where(torch.isfinite(est), est, torch.zeros_like(est))


def lobe_directions(reference, wi: torch.Tensor, angle: float, generator: torch.Generator | None = None,
                    uv: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Training directions near the reference's lobes: its own sample, spread over a cone of half-angle
    ``angle`` (the mollified lobe, not only its core). Returns (wo [N,3], ok [N]): ``ok`` is False where
    the sample failed or fell at or below the horizon (the caller keeps another direction there)."""
    u = torch.rand(wi.shape[0], 2, generator=generator).to(wi.device)
    ws, _, pdf = reference.sample(wi, u, ShadingPoint(uv=uv))
    if angle > 0:
        ws = cone_jitter(torch.where(torch.isfinite(ws), ws, wi), angle, 1, generator)
    ok = (pdf > 0) & (ws[:, 2] > 1e-4) & torch.isfinite(ws).all(-1)
    return ws, ok
