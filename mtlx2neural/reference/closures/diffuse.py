"""pbrlib diffuse closures: ``oren_nayar_diffuse_bsdf`` and ``burley_diffuse_bsdf``.

Both follow MaterialX's hardware code: forward-facing normal, cosines clamped
to [M_FLOAT_EPS, 1], response = color weight f_shape NdotL / pi (cosine
included), throughput 0. Oren-Nayar has MaterialX 1.39's optional energy
compensation (the OpenPBR/Fujii form). Both are cosine-sampled.
"""

from __future__ import annotations

import math

import torch

from mtlx2neural.reference.closures.base import CosineSampledLobe
from mtlx2neural.reference.vec import FLOAT_EPS, INV_PI, dot, forward_facing, normalize

FUJII_1 = 0.5 - 2.0 / (3.0 * math.pi)
FUJII_2 = 2.0 / 3.0 - 28.0 / (15.0 * math.pi)


def _cosines(lobe, wi, wo):
    n = forward_facing(lobe.p["normal"].expand_as(wi), wi)
    n_dot_v = dot(n, wi).clamp(FLOAT_EPS, 1.0)
    n_dot_l = dot(n, wo).clamp(FLOAT_EPS, 1.0)
    return n, n_dot_v, n_dot_l


def fujii_dir_albedo(cos_theta, r):
    a = 1.0 / (1.0 + FUJII_1 * r)
    b = r * a
    si = (1.0 - cos_theta * cos_theta).clamp_min(0.0).sqrt()
    g = si * (cos_theta.clamp(-1, 1).acos() - si * cos_theta) + \
        2.0 * ((si / cos_theta) * (1.0 - si * si * si) - si) / 3.0
    return a + b * g * INV_PI


def fujii_avg_albedo(r):
    return (1.0 + FUJII_2 * r) / (1.0 + FUJII_1 * r)


class OrenNayarLobe(CosineSampledLobe):
    category = "oren_nayar_diffuse_bsdf"

    def eval(self, wi, wo):
        n, n_dot_v, n_dot_l = _cosines(self, wi, wo)
        l_dot_v = dot(wo, wi).clamp(FLOAT_EPS, 1.0)
        r, color = self.p["roughness"], self.p["color"]
        s = l_dot_v - n_dot_l * n_dot_v
        comp = self.p.get("energy_compensation")
        if comp is not None and bool((comp > 0).any()):
            diffuse = torch.where(comp > 0, self._compensated(n_dot_v, n_dot_l, s, r, color),
                                  self._qualitative(n_dot_v, n_dot_l, s, r) * color)
        else:  # grey shape times colour: keep the scalar part [N,1] as long as possible
            diffuse = (self._qualitative(n_dot_v, n_dot_l, s, r) * n_dot_l) * color
            return self._weight_mask(diffuse * (self.weight * INV_PI), torch.zeros_like(diffuse))
        response = diffuse * self.weight * n_dot_l * INV_PI
        return self._weight_mask(response, torch.zeros_like(response))

    @staticmethod
    def _qualitative(n_dot_v, n_dot_l, s, r):
        stinv = torch.where(s > 0, s / torch.maximum(n_dot_l, n_dot_v), torch.zeros_like(s))
        sigma2 = r * r
        a = 1.0 - 0.5 * (sigma2 / (sigma2 + 0.33))
        b = 0.45 * sigma2 / (sigma2 + 0.09)
        return a + b * stinv

    @staticmethod
    def _compensated(n_dot_v, n_dot_l, s, r, color):
        stinv = torch.where(s > 0, s / torch.maximum(n_dot_l, n_dot_v), s)
        a = 1.0 / (1.0 + FUJII_1 * r)
        single = color * a * (1.0 + r * stinv)
        ev, el, avg = fujii_dir_albedo(n_dot_v, r), fujii_dir_albedo(n_dot_l, r), fujii_avg_albedo(r)
        ms_color = color * color * avg / (1.0 - color * (1.0 - avg).clamp_min(0.0))
        multi = ms_color * (1.0 - ev).clamp_min(FLOAT_EPS) * (1.0 - el).clamp_min(FLOAT_EPS) \
            / (1.0 - avg).clamp_min(FLOAT_EPS)
        return single + multi

    def energy(self, wi):
        return (self.p["color"] * self.weight).expand(wi.shape[0], 3)


class BurleyLobe(CosineSampledLobe):
    category = "burley_diffuse_bsdf"

    def eval(self, wi, wo):
        n, n_dot_v, n_dot_l = _cosines(self, wi, wo)
        l_dot_h = dot(wo, normalize(wo + wi)).clamp(FLOAT_EPS, 1.0)
        f90 = 0.5 + 2.0 * self.p["roughness"] * l_dot_h * l_dot_h
        ref_l = 1.0 + (f90 - 1.0) * (1.0 - n_dot_l).clamp(0, 1) ** 5
        ref_v = 1.0 + (f90 - 1.0) * (1.0 - n_dot_v).clamp(0, 1) ** 5
        response = self.p["color"] * self.weight * n_dot_l * INV_PI * ref_l * ref_v
        return self._weight_mask(response, torch.zeros_like(response))

    def energy(self, wi):
        return (self.p["color"] * self.weight).expand(wi.shape[0], 3)


class TranslucentLobe(CosineSampledLobe):
    """pbrlib ``translucent_bsdf``: diffuse light from the back side of the shading normal.

    In a reflection model it contributes only where a shading normal tilts past the
    light; with the geometric normal the compiler prunes it."""

    category = "translucent_bsdf"
    flip_normal = True

    def _axis(self, wi):
        return -self.p["normal"].expand_as(wi)

    def eval(self, wi, wo):
        cos_back = dot(-self.p["normal"], wo).clamp(0.0, 1.0)
        response = self.p["color"] * self.weight * cos_back * INV_PI
        return self._weight_mask(response, torch.zeros_like(response))

    def energy(self, wi):
        return (self.p["color"] * self.weight).expand(wi.shape[0], 3)
