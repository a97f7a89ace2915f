"""The encoder (prefiltered material parameters -> latent) and the sampler network (wi, latent -> proxy)."""

from __future__ import annotations

import torch
from torch import nn

from mtlx2neural.model import proxy
from mtlx2neural.model.mlp import mlp

ISOTROPIC_SAMPLER = False
"""Measurement only (the paper's isotropic-sampler ablation, its Figure 11): SamplerNets built while it is
True restrict the proxy to an isotropic, centred specular lobe (alpha_y = alpha_x, rho = 0, zero mean
slope) and an untilted diffuse lobe; only the roughness and the lobe weights are learned. Not exportable."""


class Encoder(nn.Module):
    """MLP (3x64, ReLU) from the varying parameter channels of one texel/level to a latent code.

    Used only in training; its output is baked into the latent pyramid.
    """

    def __init__(self, in_dim: int, latent_dim: int = 8, hidden=(64, 64, 64)):
        super().__init__()
        self.net = mlp(max(in_dim, 1), hidden, latent_dim)
        self.in_dim = in_dim

    def forward(self, params: torch.Tensor) -> torch.Tensor:
        if self.in_dim == 0:  # a uniform material: the code is the (learned) output bias path
            params = torch.zeros(params.shape[0], 1, dtype=params.dtype, device=params.device)
        return self.net(params)


class SamplerNet(nn.Module):
    """MLP (3x32, ReLU) from (wi, latent) to the 9 parameters of the analytic proxy."""

    def __init__(self, latent_dim: int = 8, hidden=(32, 32, 32)):
        super().__init__()
        self.net = mlp(3 + latent_dim, hidden, 9)
        self.isotropic = bool(ISOTROPIC_SAMPLER)

    def forward(self, wi: torch.Tensor, latent: torch.Tensor) -> proxy.ProxyParams:
        p = proxy.ProxyParams.from_network(self.net(torch.cat([wi, latent], -1)))
        if self.isotropic:  # the ablation: roughness alpha_x and the lobe weights only
            zero = torch.zeros_like(p.slope_spec)
            p = proxy.ProxyParams(p.alpha[:, :1].expand_as(p.alpha), torch.zeros_like(p.rho), zero, zero, p.w_spec)
        return p

    def sample(self, wi, latent, u):
        p = self(wi, latent)
        wo = proxy.sample(wi, p, u)
        return wo, proxy.pdf(wi, wo, p)

    def pdf(self, wi, wo, latent):
        return proxy.pdf(wi, wo, self(wi, latent))
