"""pbrlib ``subsurface_bsdf`` as MaterialX's hardware shading approximates it.

MaterialX's real-time code replaces subsurface scattering with a wrapped
diffusion term: the Burley diffusion profile integrated over a sphere whose
radius comes from screen-space curvature. A BRDF sees a flat surface, where
the curvature estimate bottoms out at MaterialX's floor of 0.01, so the radius
is 100 scene units. ``describe()`` reports this lobe as approximated.
"""

from __future__ import annotations

import math

import torch

from mtlx2neural.reference.closures.base import CosineSampledLobe
from mtlx2neural.reference.vec import FLOAT_EPS, INV_PI, dot, forward_facing

FLAT_SURFACE_RADIUS = 1.0 / 0.01
_SAMPLES = 32


def burley_wrap(cos_nl, radius, mfp):
    """Integral of the Burley profile around a sphere of ``radius``; [N,1] cosines -> [N,3]."""
    theta = cos_nl.clamp(-1.0, 1.0).acos()
    shape = 1.0 / mfp.clamp_min(0.1)
    width = 2.0 * math.pi / _SAMPLES
    x = -math.pi + (torch.arange(_SAMPLES, dtype=cos_nl.dtype, device=cos_nl.device) + 0.5) * width  # [S]
    dist = radius * (2.0 * torch.sin(x * 0.5)).abs()  # [S]
    d = dist[None, :, None]
    prof = (torch.exp(-shape[:, None, :] * d) + torch.exp(-shape[:, None, :] * d / 3.0)) / d.clamp_min(FLOAT_EPS)
    cosw = torch.cos(theta[:, None, :] + x[None, :, None]).clamp_min(0.0)  # [N,S,1]
    return (prof * cosw).sum(1) / prof.sum(1)


class SubsurfaceLobe(CosineSampledLobe):
    category = "subsurface_bsdf"

    def eval(self, wi, wo):
        n = forward_facing(self.p["normal"].expand_as(wi), wi)
        sss = self.p["color"] * burley_wrap(dot(n, wo), FLAT_SURFACE_RADIUS, self.p["radius"]) * INV_PI
        response = (sss * self.weight).expand(wi.shape[0], 3)
        return self._weight_mask(response, torch.zeros_like(response))

    def energy(self, wi):
        return (self.p["color"] * self.weight).expand(wi.shape[0], 3)
