"""The neural material: latent pyramid + BRDF decoder + learned sampler (+ encoder for training).

Public methods mirror the reference's contract (docs/ARCHITECTURE.md, "Conventions", and
:mod:`mtlx2neural.contract`, shared with the reference): directions in the
local frame (z the geometric normal), of any length and any real dtype (normalised,
then converted to the model's dtype, in which results come back); NaN or Inf input
raises ``ValueError``. ``eval`` returns f * cos in linear RGB, ``sample`` returns
(wo, weight = eval / pdf, pdf), ``pdf`` is a solid-angle density. When ``wi`` or ``wo``
is at or below the horizon (z <= 0, or a zero vector) eval, pdf and the sample's
weight and pdf are 0, so ``sample``'s pdf equals ``pdf(wi, wo)`` of the direction it
returns. Spatial queries take ``uv`` [N,2] and a level of detail ``lod`` [N]
(0 = finest); the level is chosen stochastically with the random numbers ``u_level`` [N].

Training calls the decoder and sampler networks directly; these methods are the
inference API (``load_neural``, rendering, evaluation).
"""

from __future__ import annotations

import torch
from torch import nn

from mtlx2neural.contract import (
    above_horizon,
    normalize_directions,
    prepare_direction,
    prepare_directions,
    prepare_values,
    zero_below_horizon,
)
from mtlx2neural.model import proxy
from mtlx2neural.model.decoder import BrdfDecoder
from mtlx2neural.model.latent import LatentPyramid
from mtlx2neural.model.networks import Encoder, SamplerNet


class NeuralMaterial(nn.Module):
    def __init__(self, resolution: tuple[int, int], in_dim: int, latent_dim: int = 8, frames: int = 2,
                 decoder: str = "2x32", albedo_head: bool = False, analytic_cosine: bool = True):
        super().__init__()
        self.latents = LatentPyramid(*resolution, channels=latent_dim)
        self.encoder = Encoder(in_dim, latent_dim)
        self.decoder = BrdfDecoder(latent_dim, frames, decoder, albedo_head, analytic_cosine)
        self.sampler = SamplerNet(latent_dim)

    @property
    def dtype(self) -> torch.dtype:
        """The dtype of the model's parameters, in which inputs are converted and results returned."""
        return self.latents.levels[0].dtype

    @property
    def device(self) -> torch.device:
        return self.latents.levels[0].device

    def _directions(self, wi, wo):
        return prepare_directions(wi, wo, self.dtype, self.device)

    def _wi(self, wi):
        return prepare_direction("wi", wi, self.dtype, self.device)

    def _latent(self, n, uv, lod, u_level):
        dt, dev = self.dtype, self.device
        uv = prepare_values("uv", uv, dt, dev, width=(2,))
        lod = prepare_values("lod", lod, dt, dev)
        u_level = prepare_values("u_level", u_level, dt, dev)
        if uv is None:
            uv = torch.zeros(n, 2, dtype=dt, device=dev)
        lod = torch.zeros(n, dtype=dt, device=dev) if lod is None else lod
        u_level = torch.zeros(n, dtype=dt, device=dev) if u_level is None else u_level
        return self.latents(uv, lod, u_level)

    def eval(self, wi, wo, uv=None, lod=None, u_level=None):
        """f(wi, wo) * cos(wo) [N,3]; 0 when either direction is at or below the horizon."""
        wi, wo = self._directions(wi, wo)
        f = self.decoder(self._latent(wi.shape[0], uv, lod, u_level), wi, wo)
        return zero_below_horizon(f, wi, wo)

    def pdf(self, wi, wo, uv=None, lod=None, u_level=None):
        """Solid-angle density [N] of :meth:`sample` at ``wo``; 0 when wi or wo is at or below the horizon."""
        wi, wo = self._directions(wi, wo)
        pdf = self.sampler.pdf(wi, wo, self._latent(wi.shape[0], uv, lod, u_level))
        return zero_below_horizon(pdf, wi, wo)

    def sample_direction(self, wi, u, uv=None, lod=None, u_level=None):
        """(wo [N,3], pdf [N] per steradian) from the learned sampler, without evaluating the BRDF;
        ``u`` [N,2] uniform random numbers (a third column is ignored). pdf is 0 where wi or wo is at
        or below the horizon."""
        wi, wo, pdf, _ = self._sample(wi, u, uv, lod, u_level)
        return wo, pdf

    def _sample(self, wi, u, uv, lod, u_level):
        wi = self._wi(wi)
        n = wi.shape[0]
        u = prepare_values("u", u, self.dtype, self.device, rows=n, width=(2, 3))
        lat = self._latent(n, uv, lod, u_level)
        params = self.sampler(wi, lat)
        # nan_to_num guards the proxy's own numerics only (input NaN was rejected above): a failed
        # (zero) sample then counts as below the horizon, with pdf 0.
        wo = normalize_directions(torch.nan_to_num(proxy.sample(wi, params, u), nan=0.0, posinf=0.0, neginf=0.0))
        pdf = proxy.pdf(wi, wo, params)
        return wi, wo, zero_below_horizon(pdf, wi, wo), lat

    def sample(self, wi, u, uv=None, lod=None, u_level=None):
        """(wo [N,3], weight [N,3] = eval / pdf, pdf [N]) from ``u`` [N,2]; weight and pdf are 0 where
        wi or the sampled wo is at or below the horizon."""
        wi, wo, pdf, lat = self._sample(wi, u, uv, lod, u_level)
        f = self.decoder(lat, wi, wo)
        ok = above_horizon(wi, wo) & (pdf[:, None] > 0)
        weight = torch.where(ok, f / pdf.clamp_min(1e-12)[:, None], torch.zeros_like(f))
        return wo, weight, pdf
