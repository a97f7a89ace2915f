"""pbrlib ``conductor_bsdf`` (MaterialX hardware semantics).

response = D F G comp weight / (4 NdotV) with the complex-IOR conductor Fresnel
(or thin-film iridescence over it); throughput is 0: nothing reaches a base layer.
"""

from __future__ import annotations

import torch

from mtlx2neural.reference.closures.microfacet_lobe import MicrofacetLobe
from mtlx2neural.reference.fresnel import (
    CONDUCTOR,
    FresnelData,
    compute_fresnel,
    fresnel_conductor,
)
from mtlx2neural.reference.microfacet import ggx_dir_albedo, ggx_energy_compensation


class ConductorLobe(MicrofacetLobe):
    category = "conductor_bsdf"
    zero_weight_throughput = 0.0

    def __init__(self, params):
        super().__init__(params)
        self.fd = FresnelData(CONDUCTOR, ior=params["ior"], extinction=params["extinction"],
                              tf_thickness=params["thinfilm_thickness"], tf_ior=params["thinfilm_ior"])
        self.thin_film = self.fd.has_thin_film

    def fresnel(self, cos_theta):
        return compute_fresnel(cos_theta, self.fd, self.thin_film)

    def energy(self, wi):
        v, frame, n_dot_v, alpha, avg_alpha = self._setup(wi)
        f0 = fresnel_conductor(torch.ones_like(n_dot_v), self.p["ior"], self.p["extinction"])
        e = ggx_dir_albedo(n_dot_v, avg_alpha, f0, 1.0) * ggx_energy_compensation(n_dot_v, avg_alpha, f0)
        return (e * self.weight).expand(wi.shape[0], 3)
