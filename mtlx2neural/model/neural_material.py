"""The neural material: latent pyramid + BRDF decoder + learned sampler (+ encoder for training).

Public methods mirror the reference's contract (DESIGN.md): directions in the
local frame, ``eval`` returns f * cos in linear RGB, ``sample`` returns
(wo, weight = eval / pdf, pdf), ``pdf`` is a solid-angle density. Spatial
queries take ``uv`` [N,2] and a level of detail ``lod`` [N] (0 = finest);
the level is chosen stochastically with the random numbers ``u_level`` [N].
"""

from __future__ import annotations

import torch
from torch import nn

from .decoder import BrdfDecoder
from .latent import LatentPyramid
from .networks import Encoder, SamplerNet
from . import proxy


class NeuralMaterial(nn.Module):
    def __init__(self, resolution: tuple[int, int], in_dim: int, latent_dim: int = 8, frames: int = 2,
                 decoder: str = "2x32", albedo_head: bool = False, analytic_cosine: bool = True):
        super().__init__()
        self.latents = LatentPyramid(*resolution, channels=latent_dim)
        self.encoder = Encoder(in_dim, latent_dim)
        self.decoder = BrdfDecoder(latent_dim, frames, decoder, albedo_head, analytic_cosine)
        self.sampler = SamplerNet(latent_dim)

    def _latent(self, n, uv, lod, u_level, device):
        if uv is None:
            uv = torch.zeros(n, 2, device=device)
        lod = torch.zeros(n, device=device) if lod is None else lod
        u_level = torch.zeros(n, device=device) if u_level is None else u_level
        return self.latents(uv, lod, u_level)

    def eval(self, wi, wo, uv=None, lod=None, u_level=None):
        """f(wi, wo) * cos(wo) [N,3]; 0 when either direction is at or below the horizon."""
        f = self.decoder(self._latent(wi.shape[0], uv, lod, u_level, wi.device), wi, wo)
        return torch.where((wi[:, 2:3] > 0) & (wo[:, 2:3] > 0), f, torch.zeros_like(f))

    def pdf(self, wi, wo, uv=None, lod=None, u_level=None):
        lat = self._latent(wi.shape[0], uv, lod, u_level, wi.device)
        return self.sampler.pdf(wi, wo, lat)

    def sample_direction(self, wi, u, uv=None, lod=None, u_level=None):
        """(wo [N,3], pdf [N] per steradian) from the learned sampler, without evaluating the BRDF;
        ``u`` [N,2] uniform random numbers."""
        wo, pdf, _ = self._sample(wi, u, uv, lod, u_level)
        return wo, pdf

    def _sample(self, wi, u, uv, lod, u_level):
        lat = self._latent(wi.shape[0], uv, lod, u_level, wi.device)
        params = self.sampler(wi, lat)
        wo = proxy.sample(wi, params, u)
        return wo, proxy.pdf(wi, wo, params), lat

    def sample(self, wi, u, uv=None, lod=None, u_level=None):
        wo, pdf, lat = self._sample(wi, u, uv, lod, u_level)
        f = self.decoder(lat, wi, wo)
        ok = (wi[:, 2:3] > 0) & (wo[:, 2:3] > 0) & (pdf[:, None] > 0)
        weight = torch.where(ok, f / pdf.clamp_min(1e-12)[:, None], torch.zeros_like(f))
        return wo, weight, pdf
