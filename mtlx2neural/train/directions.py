"""Training directions: uniform in half/difference angles (Rusinkiewicz), and mollification cones.

Drawing (theta_h, phi_h, theta_d, phi_d) uniformly concentrates samples near the
specular configuration (small theta_h), where BRDFs vary fastest. Pairs with
either direction below the horizon are redrawn from the cosine hemisphere so
every sample is informative.
"""

from __future__ import annotations

import math

import torch


def _sph(theta, phi):
    s = theta.sin()
    return torch.stack([s * phi.cos(), s * phi.sin(), theta.cos()], -1)


def half_difference_pairs(n: int, generator: torch.Generator | None = None, device="cpu"):
    """(wi, wo) [n,3] each, uniform in half/difference angles, both in the upper hemisphere."""
    u = torch.rand(n, 4, generator=generator).to(device)
    h = _sph(u[:, 0] * (math.pi / 2), u[:, 1] * (2 * math.pi))
    d = _sph(u[:, 2] * (math.pi / 2), u[:, 3] * (2 * math.pi))
    # Frame around h: rotate d (expressed about +z) into h's frame.
    t = torch.nn.functional.normalize(torch.linalg.cross(h, torch.tensor([0.0, 1.0, 0.0], device=device)
                                                         .expand_as(h), dim=-1) + 1e-9, dim=-1)
    b = torch.linalg.cross(h, t, dim=-1)
    wi = d[:, 0:1] * t + d[:, 1:2] * b + d[:, 2:3] * h
    wo = 2.0 * (wi * h).sum(-1, keepdim=True) * h - wi
    bad = (wi[:, 2] <= 1e-4) | (wo[:, 2] <= 1e-4)
    if bool(bad.any()):
        k = int(bad.sum())
        v = torch.rand(k, 4, generator=generator).to(device)
        wi[bad] = _cosine(v[:, :2])
        wo[bad] = _cosine(v[:, 2:])
    return wi, wo


def grazing_directions(n: int, max_cos: float = 0.25, generator: torch.Generator | None = None,
                       device="cpu") -> torch.Tensor:
    """``n`` directions [n,3] near the horizon: azimuth uniform, cos(theta) = z uniform in (0, max_cos]."""
    u = torch.rand(n, 2, generator=generator).to(device)
    z = (max_cos * (1.0 - u[:, 0])).clamp_min(1e-4)  # 1 - u is in (0, 1]: never exactly on the horizon
    r = (1.0 - z * z).sqrt()
    phi = 2 * math.pi * u[:, 1]
    return torch.stack([r * phi.cos(), r * phi.sin(), z], -1)


def _cosine(u):
    phi = 2 * math.pi * u[:, 0]
    r = u[:, 1].sqrt()
    return torch.stack([r * phi.cos(), r * phi.sin(), (1 - u[:, 1]).clamp_min(1e-8).sqrt()], -1)


def cone_jitter(w: torch.Tensor, angle: float, k: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """``k`` directions per row of ``w`` [n,3], uniform in a cone of half-angle ``angle`` (radians): [n*k, 3]."""
    n = w.shape[0]
    w = w.repeat_interleave(k, 0)
    if angle <= 0:
        return w
    u = torch.rand(n * k, 2, generator=generator).to(w.device)
    cos_max = math.cos(angle)
    z = 1.0 - u[:, 0] * (1.0 - cos_max)
    r = (1.0 - z * z).clamp_min(0).sqrt()
    phi = 2 * math.pi * u[:, 1]
    local = torch.stack([r * phi.cos(), r * phi.sin(), z], -1)
    a = torch.where(w[:, 0:1].abs() < 0.9, torch.tensor([1.0, 0.0, 0.0], device=w.device),
                    torch.tensor([0.0, 1.0, 0.0], device=w.device))
    t = torch.nn.functional.normalize(torch.linalg.cross(w, a, dim=-1), dim=-1)
    b = torch.linalg.cross(w, t, dim=-1)
    return local[:, 0:1] * t + local[:, 1:2] * b + local[:, 2:3] * w
