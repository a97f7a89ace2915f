"""LEAN filtering of normal-mapped microfacet lobes (Olano and Baker 2010; LEADR, Dupuy et al. 2013).

Per texel a GGX lobe with shading normal n and alpha (a_x, a_y) along the local
x/y axes is summarised by slope moments in the geometric frame:

    s  = (-n.x / n.z, -n.y / n.z)                       first moment  (2)
    M2 = s s^T + diag(a_x^2, a_y^2) / 2                 second moment (xx, yy, xy)

using the Beckmann-equivalent slope variance a^2/2 of a lobe (GGX has no
finite variance; LEADR makes the same substitution). Moments are linear, so a
MIP level is the box average of the level below. A level's lobe is read back as

    mean slope  mu = M1          -> normal  normalize(-mu.x, -mu.y, 1)   (non-centred)
    covariance  S  = M2 - mu mu^T -> eigen-decomposition: tangent along the major axis,
                                     alpha = sqrt(2 lambda) per axis   (anisotropic)

which is exact at level 0 and keeps the lobe's energy spread at coarse levels
instead of collapsing bumps into a flat mirror (what averaging normals does).
"""

from __future__ import annotations

import torch

MIN_NZ = 0.05       # normals flatter than ~87 degrees are clamped before taking slopes
ALPHA_RANGE = (1e-4, 1.0)


def moments(normal: torch.Tensor, alpha: torch.Tensor, tangent: torch.Tensor | None = None) -> torch.Tensor:
    """[..., 3] normals and [..., 2] alphas -> [..., 5] moments (sx, sy, Mxx, Myy, Mxy).

    ``tangent`` [..., 3] (optional): the lobe's tangent, along which ``alpha[..., 0]`` lies; its angle in
    the geometric xy plane rotates the lobe's slope covariance, R diag(a_x^2, a_y^2) R^T / 2, so a rotated
    anisotropic lobe keeps its orientation (``lobe_from_moments`` reads it back as the major axis).
    ``None``: alphas along the geometric x/y axes, as before the tangent was kept."""
    nz = normal[..., 2:3].clamp_min(MIN_NZ)
    s = -normal[..., :2] / nz
    a2 = alpha * alpha * 0.5
    if tangent is None:
        return torch.cat([s, s * s + a2, s[..., 0:1] * s[..., 1:2]], -1)
    phi = torch.atan2(tangent[..., 1:2], tangent[..., 0:1])
    c, si = phi.cos(), phi.sin()
    ax2, ay2 = a2[..., 0:1], a2[..., 1:2]
    cov = torch.cat([ax2 * c * c + ay2 * si * si, ax2 * si * si + ay2 * c * c, (ax2 - ay2) * c * si], -1)
    return torch.cat([s, s * s + cov[..., :2], s[..., 0:1] * s[..., 1:2] + cov[..., 2:3]], -1)


def lobe_from_moments(m: torch.Tensor):
    """[..., 5] moments -> (normal [...,3], tangent [...,3], alpha [...,2])."""
    mu = m[..., 0:2]
    sxx = (m[..., 2:3] - mu[..., 0:1] ** 2).clamp_min(0.0)
    syy = (m[..., 3:4] - mu[..., 1:2] ** 2).clamp_min(0.0)
    sxy = m[..., 4:5] - mu[..., 0:1] * mu[..., 1:2]
    # Eigen-decomposition of the 2x2 covariance: major axis at angle theta.
    theta = 0.5 * torch.atan2(2.0 * sxy, sxx - syy)
    mean = 0.5 * (sxx + syy)
    radius = (0.25 * (sxx - syy) ** 2 + sxy * sxy).sqrt()
    lam_major, lam_minor = mean + radius, (mean - radius).clamp_min(0.0)
    alpha = torch.cat([(2.0 * lam_major).sqrt(), (2.0 * lam_minor).sqrt()], -1).clamp(*ALPHA_RANGE)
    normal = torch.cat([-mu, torch.ones_like(mu[..., :1])], -1)
    normal = normal / normal.norm(dim=-1, keepdim=True)
    t = torch.cat([theta.cos(), theta.sin(), torch.zeros_like(theta)], -1)
    t = t - (t * normal).sum(-1, keepdim=True) * normal
    tangent = t / t.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return normal, tangent, alpha
