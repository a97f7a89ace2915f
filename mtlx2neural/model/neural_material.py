"""The neural material: latent pyramid + BRDF decoder + learned sampler (+ encoder for training).

It implements :class:`mtlx2neural.contract.Material` (docs/ARCHITECTURE.md, "Conventions"), as the
reference and the analytic baseline do: directions in the local frame (z the geometric normal, x the
tangent; ``wi`` to the viewer, ``wo`` to the light, both away from the surface), of any length and any
real dtype (normalised, then converted to the model's dtype, in which results come back); NaN or Inf
input raises ``ValueError``. ``eval`` returns f * cos in linear RGB, ``sample`` returns
(wo, weight = eval / pdf, pdf), ``pdf`` is a solid-angle density. When ``wi`` or ``wo``
is at or below the horizon (z <= 0, or a zero vector) eval, pdf and the sample's
weight and pdf are 0, so ``sample``'s pdf equals ``pdf(wi, wo)`` of the direction it
returns. Where: ``at``, a :class:`~mtlx2neural.contract.ShadingPoint` (or a ``[N, 2]`` uv tensor):
``uv`` [N,2] (default (0, 0)), a level of detail ``lod`` [N] (0 = finest, the default) and
``u_level`` [N], the random numbers choosing between the two nearest levels (default 0); it has no
named parameters, so ``params`` must be empty.

Training calls the decoder and sampler networks directly; these methods are the
inference API (``load_neural``, rendering, evaluation).
"""

from __future__ import annotations

import torch
from torch import nn

from mtlx2neural.contract import (
    above_horizon,
    as_point,
    estimate_albedo,
    normalize_directions,
    prepare_direction,
    prepare_directions,
    prepare_values,
    reject_params,
    zero_below_horizon,
)
from mtlx2neural.model import proxy
from mtlx2neural.model.decoder import BrdfDecoder
from mtlx2neural.model.latent import LatentPyramid
from mtlx2neural.model.networks import Encoder, SamplerNet
from mtlx2neural.textures.surface_maps import SurfacesBeside


class NeuralMaterial(SurfacesBeside, nn.Module):
    """The neural appearance model; a :class:`~mtlx2neural.contract.Material` (eval / sample / pdf /
    albedo / describe). ``resolution`` (h, w) of the finest latent level, ``in_dim`` parameter channels
    the encoder reads in training, ``latent_dim`` channels per texel, ``frames`` learned shading frames,
    ``decoder`` the MLP's hidden layers ("2x16", "2x32", "3x64"), ``albedo_head`` an extra albedo output
    for training, ``analytic_cosine`` whether the decoder multiplies by max(0, wo.z) itself, ``tiles`` the
    trained UDIM tiles of a UDIM material (one latent pyramid each, :mod:`mtlx2neural.model.latent`; a uv
    outside them raises ``ValueError``), None otherwise; ``latent_format`` the block format its latents
    are read through (:mod:`mtlx2neural.formats.latent_codec`; ``exr``: as stored); ``environment_head``
    the per-lobe reflectance head of prefiltered environment lighting (:meth:`environment_lobes`)."""

    def __init__(self, resolution: tuple[int, int], in_dim: int, latent_dim: int = 8, frames: int = 2,
                 decoder: str = "2x32", albedo_head: bool = False, analytic_cosine: bool = True, tiles=None,
                 latent_format: str = "exr", environment_head: bool = False):
        super().__init__()
        self.latents = LatentPyramid(*resolution, channels=latent_dim, tiles=tiles, latent_format=latent_format)
        self.encoder = Encoder(in_dim, latent_dim)
        self.decoder = BrdfDecoder(latent_dim, frames, decoder, albedo_head, analytic_cosine)
        self.sampler = SamplerNet(latent_dim)
        if environment_head:  # built last: the other networks' initial weights do not depend on it
            self.decoder.add_environment_head()
        self.surface = None  # emission and opacity beside the latents (SurfacesBeside)

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
        """Latent codes [N, latent_dim] at ``uv``/``lod``/``u_level`` (checked; None: (0, 0), level 0, 0)."""
        dt, dev = self.dtype, self.device
        uv = prepare_values("uv", uv, dt, dev, width=(2,))
        lod = prepare_values("lod", lod, dt, dev)
        u_level = prepare_values("u_level", u_level, dt, dev)
        if uv is None:
            uv = torch.zeros(n, 2, dtype=dt, device=dev)
        lod = torch.zeros(n, dtype=dt, device=dev) if lod is None else lod
        u_level = torch.zeros(n, dtype=dt, device=dev) if u_level is None else u_level
        return self.latents(uv, lod, u_level)

    def _latent_at(self, n, at):
        p = as_point(at)
        reject_params(p, "NeuralMaterial")
        return self._latent(n, p.uv, p.lod, p.u_level)

    def eval(self, wi, wo, at=None):
        """f(wi, wo) * max(0, wo.z): [N,3] linear RGB, the cosine included (exactly, with
        ``analytic_cosine``; learned otherwise); 0 when either direction is at or below the horizon.
        ``wi`` (to the viewer), ``wo`` (to the light) [N,3] in the local frame (z normal, x tangent);
        ``at`` a ShadingPoint or a [N,2] uv tensor."""
        wi, wo = self._directions(wi, wo)
        f = self.decoder(self._latent_at(wi.shape[0], at), wi, wo)
        return zero_below_horizon(f, wi, wo)

    def pdf(self, wi, wo, at=None):
        """Solid-angle density [N] (1/sr, no cosine) of :meth:`sample` at ``wo`` (the learned proxy's);
        0 when wi or wo is at or below the horizon. Inputs as for :meth:`eval`."""
        wi, wo = self._directions(wi, wo)
        pdf = self.sampler.pdf(wi, wo, self._latent_at(wi.shape[0], at))
        return zero_below_horizon(pdf, wi, wo)

    def sample_direction(self, wi, u, at=None):
        """(wo [N,3], pdf [N] per steradian) from the learned sampler without evaluating the decoder: the
        first and last of :meth:`sample`'s results, cheaper (for sampling-efficiency measurements).
        ``u`` [N,2] uniform random numbers (a third column is ignored)."""
        wi, wo, pdf, _ = self._sample(wi, u, at)
        return wo, pdf

    def _sample(self, wi, u, at):
        wi = self._wi(wi)
        n = wi.shape[0]
        u = prepare_values("u", u, self.dtype, self.device, rows=n, width=(2, 3))
        lat = self._latent_at(n, at)
        params = self.sampler(wi, lat)
        # nan_to_num guards the proxy's own numerics only (input NaN was rejected above): a failed
        # (zero) sample then counts as below the horizon, with pdf 0.
        wo = normalize_directions(torch.nan_to_num(proxy.sample(wi, params, u), nan=0.0, posinf=0.0, neginf=0.0))
        pdf = proxy.pdf(wi, wo, params)
        return wi, wo, zero_below_horizon(pdf, wi, wo), lat

    def sample(self, wi, u, at=None):
        """(wo [N,3] unit, local frame; weight [N,3] = eval / pdf, the cosine included; pdf [N] per
        steradian) from ``u`` [N,2] (a third column is ignored), drawn from the learned proxy; weight and
        pdf are 0 where wi or the sampled wo is at or below the horizon. ``at`` as for :meth:`eval`."""
        wi, wo, pdf, lat = self._sample(wi, u, at)
        f = self.decoder(lat, wi, wo)
        ok = above_horizon(wi, wo) & (pdf[:, None] > 0)
        weight = torch.where(ok, f / pdf.clamp_min(1e-12)[:, None], torch.zeros_like(f))
        return wo, weight, pdf

    def albedo(self, wi, at=None, samples: int = 256, seed: int = 0):
        """Directional albedo [N,3] (eval integrated over wo, cosine included):
        :func:`~mtlx2neural.contract.estimate_albedo` over the learned sampler; 0 when wi is at or below
        the horizon. ``wi`` and ``at`` as for :meth:`eval`. (The optional albedo head is a training aid,
        not used here.)"""
        return estimate_albedo(self, self._wi(wi), at, samples, seed)

    def environment_lobes(self, wi, at=None):
        """The learned sampler's lobes and the reflectance each lobe of the environment path carries, for
        prefiltered environment lighting (:mod:`mtlx2neural.render.prefiltered`): (``wi`` checked [N,3],
        :class:`.proxy.ProxyParams`, reflectance [N, 3, 3] of the sharp, the specular and the diffuse lobe,
        linear RGB, 0 where wi is at or below the horizon). RuntimeError when the model has no environment head."""
        wi = self._wi(wi)
        lat = self._latent_at(wi.shape[0], at)
        c = self.decoder.predict_lobe_reflectance(lat, wi)
        return wi, self.sampler(wi, lat), torch.where(wi[:, None, 2:3] > 0, c, torch.zeros_like(c))

    @property
    def has_environment_head(self) -> bool:
        return self.decoder.environment is not None

    def describe(self) -> dict:
        """Sizes and settings: latent resolution (h, w, per tile) and levels, the UDIM tiles (None: not
        UDIM), latent channels, learned frames, the decoder's hidden layers, whether it applies the cosine analytically or has an albedo head, and
        parameter counts (the encoder only trains; the rest is what an export stores)."""
        dec = self.decoder

        def count(module) -> int:
            return sum(p.numel() for p in module.parameters())

        return {"kind": "neural", "resolution": list(self.latents.resolution), "udim_tiles": self.latents.tile_list,
                "levels": self.latents.num_levels, "latent_dim": self.latents.channels, "frames": dec.frames,
                "decoder_hidden": list(dec.hidden), "analytic_cosine": dec.analytic_cosine,
                "albedo_head": dec.albedo is not None, "environment_head": dec.environment is not None,
                "sampler_hidden": [m.out_features for m in
                                                                          self.sampler.net[:-1:2]],
                "parameters": {"latents": count(self.latents), "decoder": count(dec),
                               "sampler": count(self.sampler), "encoder": count(self.encoder)},
                "dtype": str(self.dtype).removeprefix("torch."), "device": str(self.device)}
