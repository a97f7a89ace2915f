"""Analytic isotropic BRDFs for the MERL tests, and MERL-format files written from them.

The MERL data set may not be redistributed, so the tests never read a measured file: they write the
format (:func:`mtlx2neural.formats.merl.tabulate` + ``write_merl``) from a BRDF known in closed form
and check the reader against it."""

from __future__ import annotations

import math
from pathlib import Path

import torch

from mtlx2neural.formats.merl import tabulate, write_merl


def ggx_plastic(kd=(0.45, 0.25, 0.08), ks=0.9, alpha=0.25, f0=0.04):
    """f(wi, wo) [N,3] (1/sr, no cosine) of a Lambertian base plus a GGX specular lobe with Schlick's
    Fresnel and the separable Smith shadowing: isotropic and reciprocal, as a MERL table assumes."""

    def brdf(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        ci, co = wi[:, 2].clamp_min(1e-6), wo[:, 2].clamp_min(1e-6)
        h = wi + wo
        h = h / h.norm(dim=-1, keepdim=True)
        ch = h[:, 2].clamp_min(0.0)
        a2 = alpha * alpha
        d = a2 / (math.pi * (ch * ch * (a2 - 1.0) + 1.0) ** 2)

        def g1(c):
            return 2.0 * c / (c + torch.sqrt(a2 + (1.0 - a2) * c * c))

        f = f0 + (1.0 - f0) * (1.0 - (wi * h).sum(-1).clamp(0.0, 1.0)) ** 5
        spec = ks * d * g1(ci) * g1(co) * f / (4.0 * ci * co)
        return torch.tensor(kd, dtype=wi.dtype)[None] / math.pi + spec[:, None]

    return brdf


def write_sample(path: Path, brdf=None, dims=(90, 90, 180)) -> Path:
    """``path`` written as a MERL file of ``brdf`` (default :func:`ggx_plastic`) on a ``dims`` table."""
    return write_merl(path, tabulate(brdf or ggx_plastic(), dims))
