"""pbrlib ``sheen_bsdf`` in both MaterialX 1.39 modes.

- ``conty_kulla`` (Imageworks sheen): D_sheen / (4 (NdotL + NdotV - NdotL NdotV)) * NdotL,
  albedo from MaterialX's rational fit (clamped to [0,1]).
- ``zeltner``: the LTC sheen of Zeltner et al. 2022 (MaterialX's fits), scaled by its albedo.

throughput = 1 - albedo(NdotV) weight. Sampling is cosine about the shading normal.
"""

from __future__ import annotations

import math

import torch

from mtlx2neural.reference.closures.base import CosineSampledLobe
from mtlx2neural.reference.vec import (
    FLOAT_EPS,
    INV_PI,
    cross,
    dot,
    forward_facing,
    normalize,
    tangent_frame,
)


def imageworks_albedo(n_dot_v, r):
    num = 13.67300 - 68.78018 * n_dot_v + 799.08825 * r - 905.00061 * n_dot_v * r \
        + 60.28956 * n_dot_v ** 2 + 1086.96473 * r ** 2
    den = 1.0 + 61.57746 * n_dot_v + 442.78211 * r + 2597.49308 * n_dot_v * r \
        + 121.81241 * n_dot_v ** 2 + 3045.55075 * r ** 2
    return (num / den).clamp(0.0, 1.0)


def zeltner_albedo(x, y):
    s = y * (0.0206607 + 1.58491 * y) / (0.0379424 + y * (1.32227 + y))
    m = y * (-0.193854 + y * (-1.14885 + y * (1.7932 - 0.95943 * y * y))) / (0.046391 + y)
    o = y * (0.000654023 + (-0.0207818 + 0.119681 * y) * y) / (1.26264 + y * (-1.92021 + y))
    return torch.exp(-0.5 * ((x - m) / s) ** 2) / (s * math.sqrt(2.0 * math.pi)) + o


def _ltc_inv(x, y):
    a_inv = (2.58126 * x + 0.813703 * y) * y / (1.0 + 0.310327 * x * x + 2.60994 * x * y)
    b_inv = (1.0 - x).clamp_min(0).sqrt() * (y - 1.0) * y * y * y / \
        (0.0000254053 + 1.71228 * x - 1.71506 * x * y + 1.34174 * y * y)
    return a_inv, b_inv


class SheenLobe(CosineSampledLobe):
    category = "sheen_bsdf"
    zero_weight_throughput = 1.0

    @property
    def zeltner(self) -> bool:
        return self.p.get("mode", "conty_kulla") == "zeltner"

    def _albedo(self, n_dot_v):
        r = self.p["roughness"]
        if self.zeltner:
            return zeltner_albedo(n_dot_v, r.clamp(0.01, 1.0))
        return imageworks_albedo(n_dot_v, r)

    def eval(self, wi, wo):
        n = forward_facing(self.p["normal"].expand_as(wi), wi)
        n_dot_v = dot(n, wi).clamp(FLOAT_EPS, 1.0)
        r, color = self.p["roughness"], self.p["color"]
        if self.zeltner:
            r = r.clamp(0.01, 1.0)
            x = wi - n * n_dot_v
            len2 = (x * x).sum(-1, keepdim=True)
            fallback = tangent_frame(n, torch.zeros_like(n))[0]
            x = torch.where(len2 > 0, x * torch.rsqrt(len2.clamp_min(1e-30)), fallback)
            y = cross(n, x)
            w = torch.cat([dot(wo, x), dot(wo, y), dot(wo, n)], -1)
            a_inv, b_inv = _ltc_inv(n_dot_v, r)
            w0 = torch.cat([a_inv * w[..., 0:1] + b_inv * w[..., 2:3], a_inv * w[..., 1:2], w[..., 2:3]], -1)
            len2 = (w0 * w0).sum(-1, keepdim=True).clamp_min(1e-30)
            fr = color * w0[..., 2:3].clamp_min(0.0) * INV_PI * (a_inv / len2) ** 2
            albedo = zeltner_albedo(n_dot_v, r)
            response = albedo * fr * self.weight
        else:
            h = normalize(wo + wi)
            n_dot_l = dot(n, wo).clamp(FLOAT_EPS, 1.0)
            n_dot_h = dot(n, h).clamp(FLOAT_EPS, 1.0)
            inv_r = 1.0 / r.clamp_min(0.005)
            sin2 = (1.0 - n_dot_h * n_dot_h).clamp_min(0.0)
            d = (2.0 + inv_r) * sin2.pow(inv_r * 0.5) / (2.0 * math.pi)
            fr = color * d / (4.0 * (n_dot_l + n_dot_v - n_dot_l * n_dot_v))
            albedo = imageworks_albedo(n_dot_v, r)
            response = fr * n_dot_l * self.weight
        throughput = (1.0 - albedo * self.weight).expand_as(response)
        return self._weight_mask(response, throughput)

    def throughput(self, wi):
        n = forward_facing(self.p["normal"].expand_as(wi), wi)
        tp = (1.0 - self._albedo(dot(n, wi).clamp(FLOAT_EPS, 1.0)) * self.weight).expand(wi.shape[0], 3)
        return torch.where(self.weight < FLOAT_EPS, torch.ones_like(tp), tp)

    def energy(self, wi):
        n = forward_facing(self.p["normal"].expand_as(wi), wi)
        return (self._albedo(dot(n, wi).clamp(FLOAT_EPS, 1.0)) * self.p["color"] * self.weight).expand(wi.shape[0], 3)
