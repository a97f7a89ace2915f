"""Fresnel models of MaterialX's pbrlib: dielectric, conductor, generalized
Schlick (Hoffman's F82 form) and thin-film iridescence (Belcour and Barla 2017).

``cos_theta`` is the cosine between the view direction and the microfacet
normal, shaped ``[N, 1]``; results are RGB reflectances ``[N, 3]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

DIELECTRIC, CONDUCTOR, SCHLICK = 0, 1, 2
AIRY_ITERATIONS = 2  # MaterialX's default hwAiryFresnelIterations


@dataclass
class FresnelData:
    """Parameters of one Fresnel model; tensors broadcast against ``[N, 3]``."""

    model: int
    ior: torch.Tensor | None = None         # [.,1] dielectric or [.,3] conductor
    extinction: torch.Tensor | None = None  # [.,3] conductor
    f0: torch.Tensor | None = None          # [.,3] Schlick
    f82: torch.Tensor | None = None
    f90: torch.Tensor | None = None
    exponent: torch.Tensor | None = None    # [.,1]
    tf_thickness: torch.Tensor | None = None  # [.,1] nanometres; > 0 enables thin film
    tf_ior: torch.Tensor | None = None

    @property
    def has_thin_film(self) -> bool:
        return self.tf_thickness is not None and bool((self.tf_thickness > 0).any())


def ior_to_f0(ior):
    return ((ior - 1.0) / (ior + 1.0)) ** 2


def f0_to_ior(f0):
    s = f0.clamp(0.01, 0.99).sqrt()
    return (1.0 + s) / (1.0 - s)


def schlick_pow(x: torch.Tensor, exponent: torch.Tensor) -> torch.Tensor:
    """x**exponent for x in [0,1], with 0**e = 0 for e > 0 (no NaN at x = 0)."""
    return torch.where(x > 0, x.clamp_min(1e-30).pow(exponent), torch.zeros_like(x * exponent))


def fresnel_dielectric(c, ior):
    """Unpolarised Fresnel reflectance of a real IOR; 1 under total internal reflection."""
    g2 = ior * ior + c * c - 1.0
    g = g2.clamp_min(0.0).sqrt()
    a = ((g - c) / (g + c).clamp_min(1e-20)) ** 2
    b = (((g + c) * c - 1.0) / ((g - c) * c + 1.0)) ** 2
    return torch.where(g2 < 0.0, torch.ones_like(g2), 0.5 * a * (1.0 + b))


def _polarized(c2, s2, x, t2):
    """(Rp, Rs) from cos^2, sin^2, x = |eta^2 - sin^2| (a^2 + b^2 for a conductor) and t2 = 2 a cos."""
    t1 = x + c2
    rs = (t1 - t2) / (t1 + t2).clamp_min(1e-20)
    t3 = c2 * x + s2 * s2
    t4 = t2 * s2
    rp = rs * (t3 - t4) / (t3 + t4).clamp_min(1e-20)
    return rp, rs


def fresnel_dielectric_polarized(cos_theta, ior):
    """(Rp, Rs) of a dielectric interface."""
    c2 = cos_theta.clamp(0.0, 1.0) ** 2
    s2 = 1.0 - c2
    t0 = (ior * ior - s2).clamp_min(0.0)
    return _polarized(c2, s2, t0, 2.0 * t0.sqrt() * cos_theta)


def fresnel_conductor_polarized(cos_theta, n, k):
    """(Rp, Rs) of a conductor with complex IOR n + ik."""
    c2 = cos_theta.clamp(0.0, 1.0) ** 2
    s2 = 1.0 - c2
    n2, k2 = n * n, k * k
    t0 = n2 - k2 - s2
    a2b2 = (t0 * t0 + 4.0 * n2 * k2).sqrt()
    a = (0.5 * (a2b2 + t0)).clamp_min(0.0).sqrt()
    return _polarized(c2, s2, a2b2, 2.0 * a * cos_theta)


def fresnel_conductor(cos_theta, n, k):
    rp, rs = fresnel_conductor_polarized(cos_theta, n, k)
    return 0.5 * (rp + rs)


_COS_MAX = 1.0 / 7.0
_COS_FACTOR = 1.0 / (_COS_MAX * (1.0 - _COS_MAX) ** 6)


def fresnel_hoffman_schlick(cos_theta, fd: FresnelData):
    """Generalized Schlick with Hoffman's F82 tint term."""
    x = cos_theta.clamp(0.0, 1.0)
    base_max = fd.f0 + (fd.f90 - fd.f0) * schlick_pow(torch.full_like(fd.exponent, 1.0 - _COS_MAX), fd.exponent)
    a = base_max * (1.0 - fd.f82) * _COS_FACTOR
    return fd.f0 + (fd.f90 - fd.f0) * schlick_pow(1.0 - x, fd.exponent) - a * x * (1.0 - x) ** 6


def _conductor_phase_polarized(cos_theta, eta1, eta2, kappa2):
    k2 = kappa2 / eta2
    sin2 = 1.0 - cos_theta * cos_theta
    a = eta2 * eta2 * (1.0 - k2 * k2) - eta1 * eta1 * sin2
    b = (a * a + (2.0 * eta2 * eta2 * k2) ** 2).sqrt()
    u = ((a + b) / 2.0).clamp_min(0).sqrt()
    v = ((b - a) / 2.0).clamp_min(0.0).sqrt()
    phi_s = torch.atan2(2.0 * eta1 * v * cos_theta, u * u + v * v - (eta1 * cos_theta) ** 2)
    phi_p = torch.atan2(2.0 * eta1 * eta2 * eta2 * cos_theta * (2.0 * k2 * u - (1.0 - k2 * k2) * v),
                        (eta2 * eta2 * (1.0 + k2 * k2) * cos_theta) ** 2 - eta1 * eta1 * (u * u + v * v))
    return phi_p, phi_s


_SENS_VAL = (5.4856e-13, 4.4201e-13, 5.2481e-13)
_SENS_POS = (1.6810e+06, 1.7953e+06, 2.2084e+06)
_SENS_VAR = (4.3278e+09, 9.3046e+09, 6.6121e+09)


def _eval_sensitivity(opd, shift):
    """Fourier transform of the CIE XYZ sensitivity (Gaussian fits), evaluated at phase 2 pi opd."""
    dev = {"dtype": opd.dtype, "device": opd.device}
    val, pos, var = (torch.tensor(t, **dev) for t in (_SENS_VAL, _SENS_POS, _SENS_VAR))
    phase = 2.0 * math.pi * opd
    xyz = val * (2.0 * math.pi * var).sqrt() * torch.cos(pos * phase + shift) * torch.exp(-var * phase * phase)
    extra = 9.7470e-14 * math.sqrt(2.0 * math.pi * 4.5282e+09) * torch.cos(2.2399e+06 * phase + shift[..., 0:1]) \
        * torch.exp(-4.5282e+09 * phase * phase)
    xyz = xyz + torch.cat([extra, torch.zeros_like(extra), torch.zeros_like(extra)], -1)
    return xyz / 1.0685e-7


# XYZ -> linear RGB (CIE 1931 RGB with equal-energy white), rows act on (X, Y, Z).
_XYZ_TO_RGB = ((2.3706743, -0.9000405, -0.4706338),
               (-0.5138850, 1.4253036, 0.0885814),
               (0.0052982, -0.0146949, 1.0093968))


def fresnel_airy(cos_theta, fd: FresnelData):
    """Thin-film iridescent reflectance over the base Fresnel model (RGB, clamped to [0,1])."""
    eta1 = 1.0
    eta2 = fd.tf_ior.clamp_min(eta1)
    if fd.model == SCHLICK:
        eta3 = f0_to_ior(fd.f0)
        kappa3 = torch.zeros_like(eta3)
    else:
        eta3 = fd.ior.expand(*fd.ior.shape[:-1], 3) if fd.ior.shape[-1] == 1 else fd.ior
        kappa3 = fd.extinction if fd.extinction is not None else torch.zeros_like(eta3)
    cos_t2 = 1.0 - (1.0 - cos_theta * cos_theta) * (eta1 / eta2) ** 2
    cos_t = cos_t2.clamp_min(0.0).sqrt()

    r12p, r12s = fresnel_dielectric_polarized(cos_theta, eta2 / eta1)
    tir = cos_t2 <= 0.0
    r12p = torch.where(tir, torch.ones_like(r12p), r12p)
    r12s = torch.where(tir, torch.ones_like(r12s), r12s)
    t121p, t121s = 1.0 - r12p, 1.0 - r12s

    if fd.model == SCHLICK:
        f = fresnel_hoffman_schlick(cos_t, fd)
        r23p = r23s = 0.5 * f
        phi23p = torch.where(eta3 < eta2, math.pi, 0.0) * torch.ones_like(eta3)
        phi23s = phi23p
    else:
        r23p, r23s = fresnel_conductor_polarized(cos_t, eta3 / eta2, kappa3 / eta2)
        phi23p, phi23s = _conductor_phase_polarized(cos_t, eta2, eta3, kappa3)

    cos_b = torch.cos(torch.atan(eta2 / eta1))
    phi21p = torch.where(cos_theta < cos_b, 0.0, math.pi) * torch.ones_like(cos_theta)
    phi21s = torch.full_like(cos_theta, math.pi)
    r123p = (r12p * r23p).clamp_min(0.0).sqrt()
    r123s = (r12s * r23s).clamp_min(0.0).sqrt()

    opd = 2.0 * eta2 * cos_t * (fd.tf_thickness * 1.0e-9)
    total = 0.0
    for r12, t121, r23, r123, phi23, phi21 in ((r12p, t121p, r23p, r123p, phi23p, phi21p),
                                               (r12s, t121s, r23s, r123s, phi23s, phi21s)):
        rs = t121 * t121 * r23 / (1.0 - r12 * r23).clamp_min(1e-20)
        total = total + r12 + rs
        cm = rs - t121
        for m in range(1, AIRY_ITERATIONS + 1):
            cm = cm * r123
            total = total + cm * 2.0 * _eval_sensitivity(m * opd, m * (phi23 + phi21))
    xyz = 0.5 * total
    m = torch.tensor(_XYZ_TO_RGB, dtype=xyz.dtype, device=xyz.device)
    return (xyz @ m.T).clamp(0.0, 1.0)


def compute_fresnel(cos_theta, fd: FresnelData, thin_film: bool):
    """MaterialX mx_compute_fresnel: per-sample thin film where thickness > 0.

    Returns [N,3], or [N,1] for a dielectric without thin film (it is grey)."""
    if fd.model == DIELECTRIC:
        base = fresnel_dielectric(cos_theta, fd.ior)  # grey: stays [N,1] until a colour multiplies it
    elif fd.model == CONDUCTOR:
        base = fresnel_conductor(cos_theta, fd.ior, fd.extinction)
    else:
        base = fresnel_hoffman_schlick(cos_theta, fd)
    if not thin_film:
        return base
    return torch.where(fd.tf_thickness > 0.0, fresnel_airy(cos_theta, fd), base)
