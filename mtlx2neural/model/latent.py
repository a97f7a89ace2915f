"""The latent texture pyramid: one 8-channel code per texel per MIP level.

Level 0 matches the material's finest texture grid; each level halves it down
to 1x1. A spatially uniform material has a single level of one texel. At
render time a level is chosen stochastically between the two nearest to the
requested level of detail (probability = fractional part), and read bilinearly
within that level with periodic wrapping; uv (0,0) is the bottom-left corner,
row 0 the top, as image files store it.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from mtlx2neural.imaging.grid_lookup import bilinear_periodic


def level_shapes(height: int, width: int) -> list[tuple[int, int]]:
    shapes = [(height, width)]
    while shapes[-1] != (1, 1):
        h, w = shapes[-1]
        shapes.append((max(1, math.ceil(h / 2)), max(1, math.ceil(w / 2))))
    return shapes


class LatentPyramid(nn.Module):
    def __init__(self, height: int = 1, width: int = 1, channels: int = 8, init_std: float = 0.0):
        super().__init__()
        self.channels = channels
        self.levels = nn.ParameterList(
            nn.Parameter(torch.randn(channels, h, w) * init_std) for h, w in level_shapes(height, width))

    @property
    def num_levels(self) -> int:
        return len(self.levels)

    def choose_levels(self, lod: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Stochastic level per query: floor(lod) + 1 with probability frac(lod), clamped."""
        lod = lod.clamp(0.0, self.num_levels - 1)
        k = lod.floor()
        k = k + (u < (lod - k)).to(k.dtype)
        return k.clamp(0, self.num_levels - 1).long()

    def fetch(self, uv: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
        """Bilinear latents [N, C] at uv [N,2] from integer ``level`` [N] (0 = finest).

        A uniform material's single 1x1 code is returned as it is, broadcast to the N queries
        (bilinear weights over one texel sum to 1); otherwise each level present in the batch is
        read with :func:`bilinear_periodic`. (A single gather over all levels laid end to end was
        measured slower on the CPU: 14 ms against 11 ms for 65k queries on a 256² pyramid.)
        """
        if self.num_levels == 1 and tuple(self.levels[0].shape[1:]) == (1, 1):
            return self.levels[0].reshape(1, self.channels).expand(uv.shape[0], -1)
        out = torch.zeros(uv.shape[0], self.channels, dtype=self.levels[0].dtype, device=uv.device)
        for k in torch.unique(level).tolist():
            idx = torch.nonzero(level == k)[:, 0]
            out = out.index_put((idx,), bilinear_periodic(self.levels[int(k)], uv[idx]))
        return out

    def forward(self, uv: torch.Tensor, lod: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return self.fetch(uv, self.choose_levels(lod, u))
