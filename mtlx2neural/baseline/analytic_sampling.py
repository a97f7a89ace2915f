"""Importance sampling of the analytic baseline (Lambert + GGX, :mod:`.analytic_model`).

A one-sample mixture of two strategies, both about the model's shading normal ``n`` (its slopes):

- *diffuse*: cosine-weighted directions about ``n``, density max(0, n.wo) / pi;
- *specular*: a microfacet normal ``h`` from GGX's distribution of visible normals seen from ``wi``
  (alpha = roughness^2, isotropic), ``wo`` the mirror reflection of ``wi`` about ``h``; density
  D(h) G1(wi) / (4 n.wi) wherever h = normalize(wi + wo) is above the shading surface (n.h > 0),
  whichever side of it ``wo`` lands on.

The specular strategy is picked with probability ``p_spec`` = E_spec / (E_spec + E_diff), estimates of
the two lobes' directional albedos at ``wi``: E_diff = luminance((1 - metalness) base), Lambert's
exactly; E_spec = luminance(F0 A + B), MaterialX's rational fit of GGX's albedo with Schlick Fresnel
(:func:`~mtlx2neural.reference.microfacet.ggx_dir_albedo_ab`). ``p_spec`` is kept within
[``P_MIN``, 1 - ``P_MIN``] so that neither strategy starves, and is 0 where ``wi`` is at or below the
shading surface (n.wi <= ``MIN_COS``), where visible normals are undefined; the diffuse strategy alone
covers the model's support (every ``wo`` with n.wo > 0), so the estimator stays unbiased.

:func:`pdf` is the exact mixture density of :func:`sample` over the whole sphere, per steradian; the
material (``AnalyticMaterial``) zeroes it where ``wi`` or ``wo`` is at or below the geometric horizon,
as the contract asks. Directions are unit ``[N, 3]`` in the local frame (z the geometric normal, x the
tangent), ``wi`` towards the viewer, both pointing away from the surface.
"""

from __future__ import annotations

import torch

from mtlx2neural.reference.microfacet import (
    ggx_dir_albedo_ab,
    sample_vndf,
    vndf_reflection_pdf,
)
from mtlx2neural.reference.vec import (
    INV_PI,
    cosine_sample,
    from_frame,
    luminance,
    tangent_frame,
    to_frame,
)

P_MIN = 0.05  # least probability of either strategy where both are defined
MIN_COS = 1e-4  # n.wi at or below this: specular sampling is off (visible normals need n.wi > 0)


def _frame(p: dict):
    n = p["normal"]
    x = torch.zeros_like(n)
    x[:, 0] = 1.0
    return tangent_frame(n, x)


def _alpha(p: dict) -> torch.Tensor:
    a = p["roughness"] ** 2
    return torch.cat([a, a], -1)


def specular_probability(p: dict, wi_local: torch.Tensor) -> torch.Tensor:
    """``p_spec`` [N,1] (module docstring) for decoded parameters ``p`` and ``wi`` in the shading frame."""
    cos_i = wi_local[:, 2:3]
    a, b = ggx_dir_albedo_ab(cos_i.clamp(MIN_COS, 1.0), p["roughness"] ** 2)
    f0 = (1 - p["metalness"]) * 0.08 * p["specular"] + p["metalness"] * p["base"]
    e_spec = luminance(f0 * a + b)[:, None]
    e_diff = luminance((1 - p["metalness"]) * p["base"])[:, None]
    ps = (e_spec / (e_spec + e_diff).clamp_min(1e-12)).clamp(P_MIN, 1 - P_MIN)
    ps = torch.nan_to_num(ps, nan=0.5)
    return torch.where(cos_i > MIN_COS, ps, torch.zeros_like(ps))


def pdf(p: dict, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """Mixture density [N] per steradian of :func:`sample` at ``wo`` (unit [N,3], local frame)."""
    frame = _frame(p)
    wi_l, wo_l = to_frame(wi, frame), to_frame(wo, frame)
    ps = specular_probability(p, wi_l)
    p_diff = wo_l[:, 2:3].clamp_min(0.0) * INV_PI
    h = wi_l + wo_l
    h = h * torch.rsqrt((h * h).sum(-1, keepdim=True).clamp_min(1e-30))
    ok = (h[:, 2:3] > 0) & (wi_l[:, 2:3] > MIN_COS)
    p_spec = vndf_reflection_pdf(wi_l, h, _alpha(p))
    p_spec = torch.where(ok & torch.isfinite(p_spec), p_spec, torch.zeros_like(p_spec))
    return ((1 - ps) * p_diff + ps * p_spec)[:, 0]


def sample(p: dict, wi: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Directions ``wo`` [N,3] (unit, or 0 where sampling failed) from ``u`` [N,2] or [N,3].

    With a third column it picks the strategy (specular when u[:, 2] < p_spec); otherwise u[:, 0] picks
    it and is rescaled to [0, 1) within the chosen interval, so the two numbers stay stratified."""
    frame = _frame(p)
    wi_l = to_frame(wi, frame)
    ps = specular_probability(p, wi_l)[:, 0]
    uu = u[:, :2].clone()
    if u.shape[1] > 2:
        spec = u[:, 2] < ps
    else:
        spec = u[:, 0] < ps
        scaled = torch.where(spec, u[:, 0] / ps.clamp_min(1e-12), (u[:, 0] - ps) / (1 - ps).clamp_min(1e-12))
        uu[:, 0] = scaled.clamp(0.0, 1.0 - 1e-7)
    diffuse = cosine_sample(uu)
    h = sample_vndf(wi_l.clamp(min=torch.tensor([-1.0, -1.0, MIN_COS], dtype=wi.dtype, device=wi.device)),
                    _alpha(p), uu)
    mirror = 2.0 * (wi_l * h).sum(-1, keepdim=True) * h - wi_l
    wo_l = torch.where(spec[:, None], mirror, diffuse)
    wo = from_frame(wo_l, frame)
    return torch.nan_to_num(wo, nan=0.0, posinf=0.0, neginf=0.0)
