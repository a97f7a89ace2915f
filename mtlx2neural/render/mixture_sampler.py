"""A BSDF sampler that draws from several materials' samplers at once: one-sample MIS over them.

:class:`MixtureSampler` picks one of its ``k`` materials per sample (uniformly, from the first uniform
number, which is then rescaled for the pick) and returns that material's direction with the *mixture's*
density, the mean of every material's :meth:`pdf` there. Used as :func:`.renderer.render_scene`'s
``sampler``, the estimate stays unbiased for any material rendered with it, and it finds the lobes of
each of the mixed materials: a model whose sharp lobe sits slightly off the reference's is sampled where it
is, not only where the reference's sampler points (the summary's sky view, :mod:`.summary_views`).
"""

from __future__ import annotations

import torch

from mtlx2neural.contract import as_point


class MixtureSampler:
    """``sample`` and ``pdf`` (the :class:`~mtlx2neural.contract.Material` contract's, local frame, solid-angle
    densities without the cosine) of an equal mixture of ``materials``' samplers. ``sample``'s weight is not
    defined for a mixture (no ``eval``): it returns zeros, and the renderer uses only the direction and pdf."""

    def __init__(self, *materials):
        if not materials:
            raise ValueError("a mixture needs at least one sampler")
        self.materials = materials

    def pdf(self, wi: torch.Tensor, wo: torch.Tensor, at=None) -> torch.Tensor:
        """Mean of the materials' densities at ``wo`` [N]."""
        return sum(m.pdf(wi, wo, at) for m in self.materials) / len(self.materials)

    def sample(self, wi: torch.Tensor, u: torch.Tensor, at=None):
        """(wo [N, 3], zeros [N, 3], mixture pdf [N]): material ``floor(u0 k)`` samples with ``(u0 k - pick,
        u1, ...)``; a sample its material fails (pdf 0) keeps pdf 0."""
        k, n = len(self.materials), wi.shape[0]
        pick = (u[:, 0] * k).floor().clamp(max=k - 1)
        rescaled = torch.cat([(u[:, 0] * k - pick)[:, None], u[:, 1:]], -1)
        point = as_point(at)
        wo, ok = torch.zeros_like(wi), torch.zeros(n, dtype=torch.bool, device=wi.device)
        for i, m in enumerate(self.materials):  # each material samples the rows it is picked for
            rows = torch.nonzero(pick == i)[:, 0]
            if len(rows):
                w, _, p = m.sample(wi[rows], rescaled[rows], point.select(rows, n))
                wo[rows], ok[rows] = w.to(wo.dtype), p > 0
        pdf = torch.where(ok, self.pdf(wi, wo, at), torch.zeros_like(ok, dtype=wi.dtype))
        return wo, torch.zeros_like(wi), pdf
