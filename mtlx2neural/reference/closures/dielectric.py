"""pbrlib ``dielectric_bsdf``, reflection part (MaterialX hardware semantics).

response = D F G comp tint weight / (4 NdotV) (the NdotL of the light integral
cancels against the BRDF's denominator); throughput = 1 - E(NdotV) comp weight,
where E is the analytic GGX albedo for F0 = ((ior-1)/(ior+1))^2, F90 = 1.
Transmission (scatter_mode T) is not a reflectance and is pruned by the compiler.
"""

from __future__ import annotations

from mtlx2neural.reference.closures.microfacet_lobe import MicrofacetLobe
from mtlx2neural.reference.fresnel import (
    DIELECTRIC,
    FresnelData,
    compute_fresnel,
    ior_to_f0,
)
from mtlx2neural.reference.microfacet import ggx_dir_albedo


class DielectricLobe(MicrofacetLobe):
    category = "dielectric_bsdf"
    zero_weight_throughput = 1.0

    def __init__(self, params):
        super().__init__(params)
        self.fd = FresnelData(DIELECTRIC, ior=params["ior"], tf_thickness=params["thinfilm_thickness"],
                              tf_ior=params["thinfilm_ior"])
        self.thin_film = self.fd.has_thin_film

    def fresnel(self, cos_theta):
        return compute_fresnel(cos_theta, self.fd, self.thin_film)

    def _scale(self):
        return self.weight * self.p["tint"].clamp_min(0.0)

    def _throughput(self, ab, comp):
        """1 - E(NdotV) comp weight, E the analytic GGX albedo for the plain dielectric F0
        (MaterialX uses it even with a thin film)."""
        e = ior_to_f0(self.p["ior"]) * ab[0] + ab[1]
        return 1.0 - e * comp * self.weight

    def energy(self, wi):
        v, frame, n_dot_v, alpha, avg_alpha = self._setup(wi)
        e = ggx_dir_albedo(n_dot_v, avg_alpha, ior_to_f0(self.p["ior"]), 1.0) * self._scale()
        return e.expand(wi.shape[0], 3)
