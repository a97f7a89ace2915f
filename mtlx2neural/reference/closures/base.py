"""The contract every reflection lobe implements.

A lobe is one pbrlib closure instantiated with batched parameters. Directions
are ``[N, 3]`` unit vectors in the local shading frame (z = geometric normal),
pointing away from the surface: ``wi`` towards the viewer, ``wo`` towards the
light. Parameters are tensors that broadcast against ``[N, C]``.

- ``eval(wi, wo)`` returns ``(response, throughput)`` exactly as MaterialX's
  hardware closures define them: ``response`` is f(wi, wo) * cos(wo) in RGB
  (the cosine is included), ``throughput`` the RGB fraction of energy that passes
  to a layer below (a function of ``wi`` only).
- ``sample(wi, u)`` maps ``u`` [N,2] uniform to a direction ``wo`` [N,3].
- ``pdf(wi, wo)`` is the solid-angle density [N] of ``sample``; it integrates
  to 1 over the sphere.
- ``energy(wi)`` [N,3] is a cheap estimate of the lobe's directional albedo,
  used only to choose lobes when sampling a mixture.
"""

from __future__ import annotations

import torch

from mtlx2neural.reference.vec import (
    FLOAT_EPS,
    INV_PI,
    cosine_sample,
    dot,
    forward_facing,
    from_frame,
    tangent_frame,
)


class Lobe:
    """Base class; subclasses set ``category`` and implement the four methods."""

    category = "lobe"
    zero_weight_throughput = 0.0  # throughput MaterialX leaves when weight < eps

    def __init__(self, params: dict):
        self.p = params

    @property
    def weight(self) -> torch.Tensor:
        return self.p["weight"]

    def _weight_mask(self, response, throughput):
        """MaterialX returns early for weight < M_FLOAT_EPS: zero response, default throughput."""
        w = self.weight
        if w.shape[0] == 1 and bool((w >= FLOAT_EPS).all()):
            return response, throughput  # a constant, live weight: nothing to mask
        off = w < FLOAT_EPS
        response = torch.where(off, torch.zeros_like(response), response)
        throughput = torch.where(off, torch.full_like(throughput, self.zero_weight_throughput), throughput)
        return response, throughput

    def eval(self, wi, wo):  # pragma: no cover - interface
        raise NotImplementedError

    def throughput(self, wi):
        return torch.full_like(wi, self.zero_weight_throughput)

    def energy(self, wi):  # pragma: no cover - interface
        raise NotImplementedError

    def sample(self, wi, u):  # pragma: no cover - interface
        raise NotImplementedError

    def pdf(self, wi, wo):  # pragma: no cover - interface
        raise NotImplementedError


class CosineSampledLobe(Lobe):
    """Lobes importance-sampled with a cosine distribution about the forward-facing shading normal."""

    flip_normal = False  # translucent lobes sample the back side

    def _axis(self, wi):
        n = forward_facing(self.p["normal"], wi)
        return -n if self.flip_normal else n

    def sample(self, wi, u):
        n = self._axis(wi)
        frame = tangent_frame(n.expand_as(wi), torch.tensor([1.0, 0.0, 0.0], dtype=wi.dtype, device=wi.device).expand_as(wi))
        return from_frame(cosine_sample(u), frame)

    def pdf(self, wi, wo):
        return (dot(self._axis(wi), wo).clamp_min(0.0) * INV_PI)[..., 0]
