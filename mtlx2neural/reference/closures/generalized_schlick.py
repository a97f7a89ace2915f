"""pbrlib ``generalized_schlick_bsdf``, reflection part (MaterialX hardware semantics).

Fresnel is Hoffman's generalized Schlick with an F82 tint: F0 = color0,
F90 = color90, F82 = color82, exponent. throughput = 1 - mean_rgb(E comp) weight,
a grey value, as MaterialX computes it.
"""

from __future__ import annotations

from mtlx2neural.reference.closures.microfacet_lobe import MicrofacetLobe
from mtlx2neural.reference.fresnel import SCHLICK, FresnelData, compute_fresnel
from mtlx2neural.reference.microfacet import ggx_dir_albedo


class GeneralizedSchlickLobe(MicrofacetLobe):
    category = "generalized_schlick_bsdf"
    zero_weight_throughput = 1.0

    def __init__(self, params):
        super().__init__(params)
        p = params
        self.fd = FresnelData(SCHLICK, f0=p["color0"].clamp_min(0), f82=p["color82"].clamp_min(0),
                              f90=p["color90"].clamp_min(0), exponent=p["exponent"],
                              tf_thickness=p["thinfilm_thickness"], tf_ior=p["thinfilm_ior"])
        self.thin_film = self.fd.has_thin_film

    def fresnel(self, cos_theta):
        return compute_fresnel(cos_theta, self.fd, self.thin_film)

    def _throughput(self, ab, comp):
        """1 - mean_rgb(E comp) weight with E = color0 A + color90 B (grey, as MaterialX)."""
        e = (self.fd.f0 * ab[0] + self.fd.f90 * ab[1]) * comp
        return 1.0 - e.mean(-1, keepdim=True) * self.weight

    def energy(self, wi):
        v, frame, n_dot_v, alpha, avg_alpha = self._setup(wi)
        e = ggx_dir_albedo(n_dot_v, avg_alpha, self.fd.f0, self.fd.f90)
        return (e * self.weight).expand(wi.shape[0], 3)
