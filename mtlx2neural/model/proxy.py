"""The analytic proxy distribution that the learned sampler drives (Zeltner et al. 2024, App. A).

A two-lobe mixture over outgoing directions ``wo`` (local frame, z = normal):

- a *diffuse* lobe: a cosine distribution about a tilted axis
  ``n_d = normalize(-slope_d.x, -slope_d.y, 1)``;
- a *specular* lobe: microfacet normals drawn from an anisotropic, correlated,
  non-centred GGX slope distribution (alpha_x, alpha_y, correlation rho, mean
  slope ``slope_s``) and reflected about ``wi``.

The network's 9 raw outputs map to parameters with the paper's activations:
alpha = 1e-4 + (1 + x / sqrt(1 + x^2)) / 2, rho = x / sqrt(1 + x^2),
slope = x sqrt(1 + x^2), and a softmax over the two lobe weights.

``sample`` and ``pdf`` are exact for each other (``pdf`` is the mixture's
solid-angle density over the whole sphere; sampled directions may fall below
the horizon, where the material is 0).

Prefiltered environment lighting adds a third, *sharp* lobe (:func:`sharp_params`): the specular lobe's
mean microfacet normal with a fixed, near-mirror width (:data:`SHARP_ALPHA`), which carries the reflectance
of a clear coat's or a polished surface's near-delta peak that one specular lobe, fitted to sample a coat
and its base together, spreads out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

PDF_MIN_COS = 1e-4  # half vectors closer than this to the horizon have zero density


@dataclass
class ProxyParams:
    """Batched proxy parameters; every field is ``[N, k]``."""

    alpha: torch.Tensor       # [N,2] GGX alpha_x, alpha_y in (1e-4, 1 + 1e-4)
    rho: torch.Tensor         # [N,1] slope correlation in (-1, 1)
    slope_spec: torch.Tensor  # [N,2] mean microfacet slope of the specular lobe
    slope_diff: torch.Tensor  # [N,2] tilt of the diffuse lobe, as a slope
    w_spec: torch.Tensor      # [N,1] probability of the specular lobe

    @staticmethod
    def from_network(raw: torch.Tensor) -> "ProxyParams":
        """Map the sampler network's 9 raw outputs [N,9] to parameters."""
        soft = raw / torch.sqrt(1.0 + raw * raw)            # tanh-like, bounded
        grow = raw * torch.sqrt(1.0 + raw * raw)            # sinh-like, unbounded slopes
        alpha = 1e-4 + 0.5 * (1.0 + soft[:, 0:2])
        w = torch.softmax(raw[:, 7:9], -1)
        return ProxyParams(alpha, soft[:, 2:3], grow[:, 3:5], grow[:, 5:7], w[:, 0:1])


SHARP_ALPHA = 0.005
"""GGX alpha of the sharp lobe (:func:`sharp_params`): about 0.3 degrees, narrower than a texel of the
environment maps a viewer filters (1.4 degrees at 256 x 128). Its exact value matters little: on the sample
CarPaint (coat alpha 0.0064) 0.003, 0.005 and 0.015 give the same prefiltered render within 1 % of HDR FLIP."""
SHARP_WEIGHT = 0.3
"""The sharp lobe's weight in the mixture whose responsibilities split the reflectance between the lobes
(``train.environment_fit``): inside its narrow cone it takes almost all of it at any weight (0.05 and 0.3
give the same render within 3 %), elsewhere almost none; of what it takes, the fit keeps only f's own peak."""
SHARP_SOLID_ANGLE = 4.0 * math.pi * SHARP_ALPHA ** 2
"""Steradians one filtered lookup of the sharp lobe stands for: 1 / its peak density at normal incidence."""


def sharp_params(p: "ProxyParams") -> "ProxyParams":
    """The sharp lobe of ``p`` as specular-only parameters: isotropic GGX of alpha :data:`SHARP_ALPHA` about
    the specular lobe's mean microfacet normal (``p.slope_spec``)."""
    return ProxyParams(torch.full_like(p.alpha, SHARP_ALPHA), torch.zeros_like(p.rho), p.slope_spec, p.slope_diff,
                       torch.ones_like(p.w_spec))


def sharp_direction(wi: torch.Tensor, p: "ProxyParams") -> torch.Tensor:
    """[N, 3] the sharp lobe's centre: ``wi`` reflected about the specular lobe's mean microfacet normal."""
    return reflect_about_slope(wi, p.slope_spec)


def reflect_about_slope(wi: torch.Tensor, slope: torch.Tensor) -> torch.Tensor:
    """[N, 3] ``wi`` reflected about the microfacet normal of ``slope`` [N, 2] (:func:`slope_axis`)."""
    h = slope_axis(slope)
    return 2.0 * (wi * h).sum(-1, keepdim=True) * h - wi


def _tangents(n: torch.Tensor):
    """Frame (s, t) around ``n`` built from the x axis, as the paper's listing does."""
    u = torch.zeros_like(n)
    u[:, 0] = 1.0
    s = u - n * (n * u).sum(-1, keepdim=True)
    s = s / s.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return s, torch.linalg.cross(n, s, dim=-1)


def slope_axis(slope: torch.Tensor) -> torch.Tensor:
    """[N, 3] the unit direction normalize(-slope.x, -slope.y, 1) of a lobe tilted by ``slope`` [N, 2]."""
    n = torch.cat([-slope, torch.ones_like(slope[:, :1])], -1)
    return n / n.norm(dim=-1, keepdim=True)


def sample_diffuse(slope: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Cosine-distributed direction about the tilted axis."""
    phi = 2.0 * math.pi * u[:, 0:1]
    r = u[:, 1:2].clamp(0, 1).sqrt()
    local = torch.cat([r * phi.cos(), r * phi.sin(), (1.0 - u[:, 1:2]).clamp_min(0).sqrt()], -1)
    n = slope_axis(slope)
    s, t = _tangents(n)
    return local[:, 0:1] * s + local[:, 1:2] * t + local[:, 2:3] * n


def pdf_diffuse(wo: torch.Tensor, slope: torch.Tensor) -> torch.Tensor:
    return ((wo * slope_axis(slope)).sum(-1) / math.pi).clamp_min(0.0)


def sample_specular(wi: torch.Tensor, p: ProxyParams, u: torch.Tensor) -> torch.Tensor:
    """Reflect ``wi`` about a microfacet normal drawn from the non-centred GGX slope density."""
    uu = u[:, 0:1].clamp(0.0, 1.0 - 1e-7)
    r = torch.sqrt(uu / (1.0 - uu))  # radial GGX slope for alpha = 1
    phi = 2.0 * math.pi * u[:, 1:2]
    x, y = r * phi.cos(), r * phi.sin()
    c = torch.sqrt((1.0 - p.rho * p.rho).clamp_min(1e-8))
    sx = p.alpha[:, 0:1] * x + p.slope_spec[:, 0:1]
    sy = p.alpha[:, 1:2] * (p.rho * x + c * y) + p.slope_spec[:, 1:2]
    h = slope_axis(torch.cat([sx, sy], -1))
    return 2.0 * (wi * h).sum(-1, keepdim=True) * h - wi


def pdf_specular(wi: torch.Tensor, wo: torch.Tensor, p: ProxyParams) -> torch.Tensor:
    h = wi + wo
    h = h / h.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    h = h * torch.where(h[:, 2:3] < 0, -1.0, 1.0)
    cos_t = h[:, 2:3]
    ok = cos_t > PDF_MIN_COS
    cos_t = cos_t.clamp_min(PDF_MIN_COS)
    sx = -h[:, 0:1] / cos_t - p.slope_spec[:, 0:1]
    sy = -h[:, 1:2] / cos_t - p.slope_spec[:, 1:2]
    c = torch.sqrt((1.0 - p.rho * p.rho).clamp_min(1e-8))
    ax, ay = p.alpha[:, 0:1], p.alpha[:, 1:2]
    norm = 1.0 / (ax * ay * c)
    x = sx / ax
    y = (ax * sy - p.rho * ay * sx) * norm
    r2 = x * x + y * y
    p22 = norm / (math.pi * (1.0 + r2) ** 2)
    pdf_h = p22 / cos_t ** 3
    jac = 4.0 * (wi * h).sum(-1, keepdim=True).abs().clamp_min(1e-12)
    return torch.where(ok, pdf_h / jac, torch.zeros_like(pdf_h))[:, 0]


def sample(wi: torch.Tensor, p: ProxyParams, u: torch.Tensor) -> torch.Tensor:
    """Pick a lobe with u[:,0] (rescaled for reuse) and sample it; returns wo [N,3]."""
    ws = p.w_spec[:, 0]
    spec = u[:, 0] < ws
    u_spec = torch.stack([u[:, 0] / ws.clamp_min(1e-12), u[:, 1]], -1)
    u_diff = torch.stack([(u[:, 0] - ws) / (1.0 - ws).clamp_min(1e-12), u[:, 1]], -1)
    wo = torch.where(spec[:, None], sample_specular(wi, p, u_spec.clamp(0, 1)),
                     sample_diffuse(p.slope_diff, u_diff.clamp(0, 1)))
    return wo / wo.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def pdf(wi: torch.Tensor, wo: torch.Tensor, p: ProxyParams) -> torch.Tensor:
    """Mixture density [N] (solid angle)."""
    ws = p.w_spec[:, 0]
    return ws * pdf_specular(wi, wo, p) + (1.0 - ws) * pdf_diffuse(wo, p.slope_diff)
