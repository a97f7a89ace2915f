"""Shared machinery of the GGX lobes (dielectric, conductor, generalized_schlick).

Evaluation follows MaterialX's reflection branch: forward-facing normal, NdotV
and NdotL clamped to [M_FLOAT_EPS, 1], anisotropic D, isotropic height-correlated
G2 with the average alpha, and Turquin energy compensation from the analytic
albedo fit. Sampling uses the GGX visible-normal distribution of the lobe's own
anisotropic alpha, so ``pdf`` is exact for ``sample`` (it is not the BRDF).
"""

from __future__ import annotations

import torch

from mtlx2neural.reference.closures.base import Lobe
from mtlx2neural.reference.microfacet import (
    average_alpha,
    ggx_dir_albedo_ab,
    ggx_energy_compensation,
    ggx_ndf,
    sample_vndf,
    smith_g2,
    vndf_reflection_pdf,
)
from mtlx2neural.reference.vec import (
    FLOAT_EPS,
    dot,
    forward_facing,
    from_frame,
    is_geometric_frame,
    normalize,
    reflect,
    tangent_frame,
    to_frame,
)


class MicrofacetLobe(Lobe):
    def __init__(self, params):
        super().__init__(params)
        retro = params.get("retroreflective")
        self.retro = retro is not None and bool((retro > 0).any())
        # Fast path: no normal/tangent map, so the lobe frame is the local frame itself.
        self.geometric = not self.retro and is_geometric_frame(params["normal"], params["tangent"])

    def _normal(self, v):
        """Forward-facing shading normal and the (X, Y, N) frame (None: the local frame)."""
        if self.geometric:
            # The normal is +z. MaterialX would flip it for wi.z < 0, but the material
            # returns 0 there anyway; the clamped cosines keep the maths finite.
            return self.p["normal"], None
        n = forward_facing(self.p["normal"].expand_as(v), v)
        return n, tangent_frame(n, self.p["tangent"].expand_as(v))

    def _setup(self, wi):
        """(V, frame, NdotV, alpha, avg_alpha) with MaterialX's clamps."""
        v = wi
        if self.retro:
            v = torch.where(self.p["retroreflective"] > 0, reflect(-wi, self.p["normal"]), wi)
        n, frame = self._normal(v)
        n_dot_v = dot(n, v).clamp(FLOAT_EPS, 1.0)
        alpha = self.p["roughness"].clamp(FLOAT_EPS, 1.0)
        return v, frame, n_dot_v, alpha, average_alpha(alpha)

    def fresnel(self, cos_theta):  # pragma: no cover - interface
        raise NotImplementedError

    def _throughput(self, ab, comp):
        """Throughput from the albedo-fit terms ``ab`` (A, B) at NdotV and the energy
        compensation ``comp``; default: nothing passes to a base layer."""
        return torch.zeros_like(ab[0])

    def _scale(self):
        return self.weight

    def eval(self, wi, wo):
        v, frame, n_dot_v, alpha, avg_alpha = self._setup(wi)
        h = normalize(wo + v)
        if frame is None:
            n_dot_l = wo[:, 2:3].clamp(FLOAT_EPS, 1.0)
        else:
            n_dot_l = dot(frame[2], wo).clamp(FLOAT_EPS, 1.0)
        v_dot_h = dot(v, h).clamp(FLOAT_EPS, 1.0)
        f = self.fresnel(v_dot_h)
        d = ggx_ndf(to_frame(h, frame), alpha)
        g = smith_g2(n_dot_l, n_dot_v, avg_alpha)
        ab = ggx_dir_albedo_ab(n_dot_v, avg_alpha)
        # MaterialX feeds the compensation F(VdotH) of the light's half vector, so a
        # layer's throughput depends on wo too.
        comp = ggx_energy_compensation(n_dot_v, avg_alpha, f, ab)
        # Scalar factors first, so that only the last products are RGB.
        response = (d * g / (4.0 * n_dot_v)) * (f * comp) * self._scale()
        throughput = self._throughput(ab, comp).expand_as(response)
        return self._weight_mask(response, throughput)

    def throughput(self, wi):
        """Throughput without a light: the compensation uses F(NdotV) (for choosing lobes)."""
        v, frame, n_dot_v, alpha, avg_alpha = self._setup(wi)
        ab = ggx_dir_albedo_ab(n_dot_v, avg_alpha)
        comp = ggx_energy_compensation(n_dot_v, avg_alpha, self.fresnel(n_dot_v), ab)
        tp = self._throughput(ab, comp).expand(wi.shape[0], 3)
        off = self.weight < FLOAT_EPS
        return torch.where(off, torch.full_like(tp, self.zero_weight_throughput), tp)

    def sample(self, wi, u):
        v, frame, n_dot_v, alpha, _ = self._setup(wi)
        v_local = to_frame(v, frame)
        v_local = torch.cat([v_local[..., :2], v_local[..., 2:3].clamp_min(FLOAT_EPS)], -1)
        h = sample_vndf(v_local, alpha, u)
        wo_local = 2.0 * dot(v_local, h) * h - v_local
        return normalize(from_frame(wo_local, frame))

    def pdf(self, wi, wo):
        v, frame, n_dot_v, alpha, _ = self._setup(wi)
        h = normalize(wo + v)
        h_local = to_frame(h, frame)
        v_local = to_frame(v, frame)
        v_local = torch.cat([v_local[..., :2], v_local[..., 2:3].clamp_min(FLOAT_EPS)], -1)
        pdf = vndf_reflection_pdf(v_local, h_local, alpha)
        ok = (h_local[..., 2:3] > 0) & (dot(v, h) > 0)
        return torch.where(ok, pdf, torch.zeros_like(pdf))[..., 0]
