"""Bilinear lookup in a ``[C, H, W]`` grid over UV space (parameter maps, latent textures).

Conventions: uv (0, 0) is the bottom-left corner, row 0 is the top (v = 1),
texel centres sit at half-integer positions, and UV space wraps (periodic).
"""

from __future__ import annotations

import torch


def bilinear_periodic(grid: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """[C, H, W] grid, [N, 2] uv -> [N, C] (in the grid's dtype promoted with uv's)."""
    c, h, w = grid.shape
    x = torch.remainder(uv[:, 0], 1.0) * w - 0.5
    y = (1.0 - torch.remainder(uv[:, 1], 1.0)) * h - 0.5
    x0, y0 = x.floor(), y.floor()
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.long(), y0.long()
    flat = grid.reshape(c, -1)
    out = 0
    for dx, dy, wgt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        idx = torch.remainder(y0 + dy, h) * w + torch.remainder(x0 + dx, w)
        out = out + flat[:, idx].T * wgt
    return out
