"""What the reference says a training row should be, per kind of material.

Two kinds, chosen by :func:`targets_for` from the parameter stack:

* :class:`UniformTargets`: a material with no varying parameter (an empty stack). Every row is the
  one BRDF: MIP level 0, no uv for the reference, and the target is the reference itself, averaged
  over the mollification cone.
* :class:`TexturedTargets`: a textured material, over a
  :class:`~mtlx2neural.textures.parameter_stack.ParameterStack` or a UDIM
  :class:`~mtlx2neural.train.udim.TiledStack` (whose lookups take true uv over the trained tiles, so
  the footprint filter needs nothing else). Rows draw a MIP level, and each target is the reference
  averaged over the row's footprint (:func:`~mtlx2neural.textures.footprint.footprint_targets`),
  mollified at every footprint point.

Both answer the same questions (:meth:`levels`, :meth:`lobe_uv`, :meth:`brdf`, :meth:`albedo`)
with the trainer's one generator, so a seeded run draws the same random numbers in the same order.
Values are cosine-weighted BRDF f * cos (or its integral over wo, the directional albedo), [N, 3]
linear RGB; directions are unit vectors in the local shading frame (z-up).
"""

from __future__ import annotations

import torch

from mtlx2neural.contract import ShadingPoint
from mtlx2neural.textures.footprint import (
    SIGMA_TEXELS,
    footprint_targets,
    sample_levels,
)
from mtlx2neural.train.config import TrainConfig
from mtlx2neural.train.directions import cone_jitter
from mtlx2neural.train.latent_init import is_textured
from mtlx2neural.train.mollify import cone_mean


class UniformTargets:
    """Targets of a uniform material: the reference needs no uv, every row is at level 0.

    ``cfg.compile`` compiles the reference's ``eval`` (its data-dependent branches break graphs, but
    the BRDF's arithmetic fuses)."""

    def __init__(self, reference, stack, cfg: TrainConfig, generator: torch.Generator):
        self.ref, self.stack, self.cfg, self.gen = reference, stack, cfg, generator
        self._eval = torch.compile(reference.eval) if cfg.compile else reference.eval

    def levels(self, n: int, device) -> torch.Tensor:
        """[n] MIP levels: all 0 (one latent code; no random numbers drawn)."""
        return torch.zeros(n, dtype=torch.long, device=device)

    def lobe_uv(self, uv: torch.Tensor) -> None:
        """The uv the reference's sampler reads for lobe directions: none."""

    def brdf(self, wi, wo, uv, level, angle: float) -> torch.Tensor:
        """[N, 3] f * cos at (``wi``, ``wo``) averaged over the mollification cone of half-angle ``angle``
        (radians) about ``wo``: the plain reference at ``angle <= 0``; with ``mollify_mis`` the cone mean
        by MIS (``mollify_samples // 2`` pairs); else the mean over ``mollify_samples`` jittered ``wo``.
        ``uv`` and ``level`` are ignored."""
        cfg = self.cfg
        if angle <= 0:
            return self._eval(wi, wo)
        if cfg.mollify_mis:
            return cone_mean(self.ref, wi, wo, angle, max(1, cfg.mollify_samples // 2), self.gen)
        k = cfg.mollify_samples
        wo_k = cone_jitter(wo, angle, k, self.gen)
        return self._eval(wi.repeat_interleave(k, 0), wo_k).view(-1, k, 3).mean(1)

    def albedo(self, wi: torch.Tensor, uv: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
        """[N, 3] one-sample estimates of the directional albedo at ``wi``: the reference's sample
        weight (``uv`` and ``level`` ignored)."""
        u = torch.rand(wi.shape[0], 2, generator=self.gen).to(wi.device)
        return self.ref.sample(wi, u)[1]


class TexturedTargets:
    """Targets of a textured (or UDIM) material: MIP levels drawn with ``cfg.level_rate``, the reference
    read at each row's uv, targets filtered over the row's footprint (``cfg.footprint_samples`` points)."""

    def __init__(self, reference, stack, cfg: TrainConfig, generator: torch.Generator, coverage=None):
        self.ref, self.stack, self.cfg, self.gen = reference, stack, cfg, generator
        self.coverage = coverage

    def levels(self, n: int, device) -> torch.Tensor:
        """[n] MIP levels in [0, levels) with P(k) ~ exp(-level_rate k)."""
        return sample_levels(n, len(self.stack.levels), self.cfg.level_rate, self.gen, device)

    def lobe_uv(self, uv: torch.Tensor) -> torch.Tensor:
        """The uv the reference's sampler reads for lobe directions: the rows' own."""
        return uv

    def brdf(self, wi, wo, uv, level, angle: float) -> torch.Tensor:
        """[N, 3] f * cos at (``wi``, ``wo``) averaged over each row's footprint (``uv``, ``level``) and
        over the mollification cone of half-angle ``angle`` (radians): with ``mollify_mis`` the cone mean
        by MIS at every footprint point (one pair each), else ``wo`` jittered once in the cone. Every level's
        points go to the reference in one call (``one_call``: half the data time of one call per level on
        a 256² grid, the same estimator)."""
        cfg = self.cfg
        if cfg.mollify_mis and angle > 0:  # the cone mean at every footprint point, one pair each
            def point_eval(wi_p, wo_p, at):
                return cone_mean(self.ref, wi_p, wo_p, angle, 1, self.gen, at)

            return footprint_targets(self.ref, self.stack, wi, wo, uv, level, cfg.footprint_samples, self.gen,
                                     point_eval, one_call=True, weight=self.coverage)
        wo_m = cone_jitter(wo, angle, 1, self.gen) if angle > 0 else wo
        return footprint_targets(self.ref, self.stack, wi, wo_m, uv, level, cfg.footprint_samples, self.gen,
                                 one_call=True, weight=self.coverage)

    def albedo(self, wi: torch.Tensor, uv: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
        """[N, 3] one-sample estimates of the directional albedo at ``wi``, each at a point of the row's
        footprint: ``uv`` plus a Gaussian offset of the level's standard deviation
        (``textures.footprint``), so the estimate's mean is the albedo averaged over the footprint, as
        the BRDF targets are (the albedo is linear in the BRDF)."""
        g, dev = self.gen, wi.device
        u = torch.rand(wi.shape[0], 2, generator=g).to(dev)
        h, w = self.stack.resolution
        sigma = SIGMA_TEXELS * torch.pow(2.0, level.to(uv.dtype))[:, None] / uv.new_tensor([w, h])
        pts = uv + sigma * torch.randn(uv.shape, generator=g, dtype=uv.dtype).to(dev)
        return self.ref.sample(wi, u, ShadingPoint(uv=pts))[1]


def targets_for(reference, stack, cfg: TrainConfig, generator: torch.Generator, coverage=None):
    """The targets of ``stack``'s kind of material (module docstring), drawing from ``generator``;
    ``coverage(uv) -> [N]`` (a cut-out's, textured materials only) weights the footprint's points."""
    if is_textured(stack):
        return TexturedTargets(reference, stack, cfg, generator, coverage)
    return UniformTargets(reference, stack, cfg, generator)
