"""GGX microfacet terms with MaterialX's hardware-shading conventions.

The directional-albedo fit and the energy compensation are the rational fits
that MaterialX's GLSL/Slang code uses by default (DIRECTIONAL_ALBEDO_ANALYTIC),
so that MaterialX's generated shaders are an exact oracle for the reference.
Angles are given by cosines w.r.t. the shading normal; ``alpha`` is GGX alpha
(roughness squared is applied upstream by roughness_anisotropy/roughness_dual).
"""

from __future__ import annotations

import torch

from mtlx2neural.reference.vec import FLOAT_EPS, PI

# Rational fit of GGX directional albedo, E = F0 * A + F90 * B, with
# A = num_A / den_A and B = num_B / den_B; each is a polynomial in x = NdotV and
# y = alpha with these 9 monomials: 1, x, y, xy, x^2, y^2, x^2 y, x y^2, x^2 y^2.
# Columns: num_A, num_B, den_A, den_B.
_ALBEDO_FIT = (
    (0.1003, 0.9345, 1.0, 1.0),
    (-0.6303, -2.323, -1.765, 0.2281),
    (9.748, 2.229, 8.263, 15.94),
    (-2.038, -3.748, 11.53, -55.83),
    (29.34, 1.424, 28.96, 13.08),
    (-8.245, -0.7684, -7.507, 41.26),
    (-26.44, 1.436, -36.11, 54.9),
    (19.99, 0.2913, 15.86, 300.2),
    (-5.448, 0.6286, 33.37, -285.1),
)


def ggx_ndf(h_local: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """Anisotropic GGX D(h) [N,1]; ``h_local`` in the (X, Y, N) frame, ``alpha`` [.,2]."""
    he = h_local[..., :2] / alpha
    denom = (he * he).sum(-1, keepdim=True) + h_local[..., 2:3] ** 2
    return 1.0 / (PI * alpha[..., 0:1] * alpha[..., 1:2] * denom * denom)


def smith_g1_aniso(v_local: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """Anisotropic Smith G1 for the direction ``v_local`` (frame coordinates) [N,1]."""
    z2 = (v_local[..., 2:3] ** 2).clamp_min(1e-20)
    t = ((v_local[..., :2] * alpha) ** 2).sum(-1, keepdim=True) / z2
    return 2.0 / (1.0 + (1.0 + t).sqrt())


def smith_g2(n_dot_l: torch.Tensor, n_dot_v: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """Height-correlated Smith masking-shadowing (isotropic, MaterialX form)."""
    a2 = alpha * alpha
    lam_l = (a2 + (1.0 - a2) * n_dot_l * n_dot_l).sqrt()
    lam_v = (a2 + (1.0 - a2) * n_dot_v * n_dot_v).sqrt()
    return 2.0 * n_dot_l * n_dot_v / (lam_l * n_dot_v + lam_v * n_dot_l)


def ggx_dir_albedo_ab(n_dot_v: torch.Tensor, alpha: torch.Tensor):
    """(A, B) [N,1] such that GGX directional albedo = F0*A + F90*B (MaterialX's analytic fit).

    Each rational term is evaluated as p0(y) + x (p1(y) + x p2(y)) with x = NdotV,
    y = alpha; alpha is usually a per-material constant, so the p_k(y) are cheap.
    """
    y = alpha
    y2 = y * y
    cols = []
    for k in range(4):
        c = [row[k] for row in _ALBEDO_FIT]
        p0 = c[0] + c[2] * y + c[5] * y2
        p1 = c[1] + c[3] * y + c[7] * y2
        p2 = c[4] + c[6] * y + c[8] * y2
        cols.append(p0 + n_dot_v * (p1 + n_dot_v * p2))
    a = (cols[0] / cols[2]).clamp(0.0, 1.0)
    b = (cols[1] / cols[3]).clamp(0.0, 1.0)
    return a, b


def ggx_dir_albedo(n_dot_v, alpha, f0, f90, ab=None):
    a, b = ab if ab is not None else ggx_dir_albedo_ab(n_dot_v, alpha)
    return f0 * a + f90 * b


def ggx_energy_compensation(n_dot_v, alpha, fss, ab=None):
    """Turquin-style multiple-scattering compensation factor 1 + F (1 - Ess) / Ess.

    ``ab``: (A, B) from :func:`ggx_dir_albedo_ab` when the caller already has them.
    """
    a, b = ab if ab is not None else ggx_dir_albedo_ab(n_dot_v, alpha)
    ess = (a + b).clamp_min(FLOAT_EPS)
    return 1.0 + fss * ((1.0 - ess) / ess)


def average_alpha(alpha: torch.Tensor) -> torch.Tensor:
    return (alpha[..., 0:1] * alpha[..., 1:2]).sqrt()


def sample_vndf(v_local: torch.Tensor, alpha: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Sample a microfacet normal from the GGX distribution of visible normals.

    Spherical-cap method (Dupuy and Benyoub 2023). ``v_local`` is the view
    direction in the (X, Y, N) frame with z > 0; returns h in the same frame.
    """
    vh = torch.cat([v_local[..., :2] * alpha, v_local[..., 2:3]], -1)
    vh = vh * torch.rsqrt((vh * vh).sum(-1, keepdim=True).clamp_min(1e-30))
    phi = 2.0 * PI * u[:, 0:1]
    z = (1.0 - u[:, 1:2]) * (1.0 + vh[..., 2:3]) - vh[..., 2:3]
    sin_t = (1.0 - z * z).clamp(0.0, 1.0).sqrt()
    c = torch.cat([sin_t * phi.cos(), sin_t * phi.sin(), z], -1)
    h = c + vh
    h = torch.cat([h[..., :2] * alpha, h[..., 2:3].clamp_min(0.0)], -1)
    return h * torch.rsqrt((h * h).sum(-1, keepdim=True).clamp_min(1e-30))


def vndf_reflection_pdf(v_local, h_local, alpha):
    """Solid-angle pdf of the reflected direction when h ~ VNDF(v): D(h) G1(v) / (4 v.z)."""
    vz = v_local[..., 2:3].clamp_min(FLOAT_EPS)
    return ggx_ndf(h_local, alpha) * smith_g1_aniso(v_local, alpha) / (4.0 * vz)
