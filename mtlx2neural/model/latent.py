"""The latent texture pyramid: one 8-channel code per texel per MIP level.

Level 0 matches the material's finest texture grid; each level halves it down
to 1x1. A spatially uniform material has a single level of one texel. At
render time a level is chosen stochastically between the two nearest to the
requested level of detail (probability = fractional part), and read bilinearly
within that level with periodic wrapping; uv (0,0) is the bottom-left corner,
row 0 the top, as image files store it.

UDIM materials (a graph that reads a ``<UDIM>`` texture set; docs/ARCHITECTURE.md, "UDIM
latents") get one pyramid per trained UDIM tile: ``tiles`` lists the tiles' UDIM numbers
(``1001 + tu + 10 * tv``) and every level is a ``[T, C, H, W]`` parameter, tile ``t`` covering
uv in ``[tu, tu+1) x [tv, tv+1)``. Inside a tile the latents are read at ``frac(uv)`` with
*clamp* addressing at the tile's edges (neighbouring tiles are unrelated textures), and a uv in
a tile that is not in ``tiles`` raises ``ValueError`` naming the tile. Without ``tiles`` (every
non-UDIM material) the levels stay ``[C, H, W]`` with periodic addressing, which is the
one-tile case of the same lookup with wrap instead of clamp.

A pyramid with a block format (``latent_format`` ``bc6h`` or ``bc1``;
:mod:`mtlx2neural.formats.latent_codec`) reads every level through the format's emulation: the values
a GPU returns for the compressed texture, differentiable so that training fine-tunes for them. The
parameters stay the uncompressed latents the encoder starts from; the emulated levels are cached while
no gradient is taken.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from mtlx2neural.formats.latent_codec import LatentCodec
from mtlx2neural.imaging.grid_lookup import bilinear_periodic, blend_texels
from mtlx2neural.imaging.udim import check_tiles, udim_of_uv


def level_shapes(height: int, width: int) -> list[tuple[int, int]]:
    shapes = [(height, width)]
    while shapes[-1] != (1, 1):
        h, w = shapes[-1]
        shapes.append((max(1, math.ceil(h / 2)), max(1, math.ceil(w / 2))))
    return shapes


def bilinear_clamp(grid: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """[C, H, W] grid, [N, 2] uv in [0, 1] -> [N, C]: bilinear with clamp-to-edge addressing (the
    conventions of :func:`~mtlx2neural.imaging.grid_lookup.bilinear_periodic`: row 0 at v = 1, texel
    centres at half-integers)."""
    _, h, w = grid.shape
    x = uv[:, 0].clamp(0.0, 1.0) * w - 0.5
    y = (1.0 - uv[:, 1].clamp(0.0, 1.0)) * h - 0.5
    x0, y0 = x.floor(), y.floor()
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.long(), y0.long()
    return blend_texels(grid, x0.clamp(0, w - 1), y0.clamp(0, h - 1), (x0 + 1).clamp(0, w - 1),
                        (y0 + 1).clamp(0, h - 1), fx, fy)


class LatentPyramid(nn.Module):
    """``height`` x ``width`` latent codes of ``channels`` channels at level 0, halved to 1x1;
    ``tiles`` (UDIM numbers, sorted) makes it a UDIM pyramid of ``[T, C, H, W]`` levels (module
    docstring); the tile list is also the persistent buffer ``tiles`` (in the state dict);
    ``latent_format`` a block format the levels are read through (``exr``: none)."""

    def __init__(self, height: int = 1, width: int = 1, channels: int = 8, init_std: float = 0.0,
                 tiles=None, latent_format: str = "exr"):
        super().__init__()
        self.codec = LatentCodec(latent_format, channels) if latent_format != "exr" else None
        self.codec_active = True  # False: read the parameters as they are (the trainer's steps before the codec's)
        self._emulated: dict[int, tuple[tuple, torch.Tensor]] = {}
        self.channels = channels
        lead = () if tiles is None else (len(tiles),)
        self.levels = nn.ParameterList(
            nn.Parameter(torch.randn(*lead, channels, h, w) * init_std) for h, w in level_shapes(height, width))
        if tiles is not None:
            tiles = check_tiles(tiles)
            self.register_buffer("tiles", torch.tensor(tiles, dtype=torch.long))
        else:
            self.tiles = None

    @property
    def tile_list(self) -> list[int] | None:
        """The trained UDIM tiles (sorted UDIM numbers), or None for a single periodic pyramid."""
        return None if self.tiles is None else [int(t) for t in self.tiles]

    @property
    def resolution(self) -> tuple[int, int]:
        """(H, W) of level 0 (per tile for a UDIM pyramid)."""
        return tuple(int(s) for s in self.levels[0].shape[-2:])

    @property
    def latent_format(self) -> str:
        """``exr`` (read as stored) or the block format the levels are read through."""
        return "exr" if self.codec is None else self.codec.format.name

    def level(self, k: int) -> torch.Tensor:
        """Level ``k`` as the lookups read it: the parameter, or its block-compressed emulation
        (cached by the parameter's version while no gradient is taken)."""
        lv = self.levels[k]
        if self.codec is None or not self.codec_active:
            return lv
        if torch.is_grad_enabled() and lv.requires_grad:
            return self.codec.emulate(lv)
        key = (lv._version, lv.data_ptr(), lv.device, lv.dtype, self.codec.codec_offset._version)
        hit = self._emulated.get(k)
        if hit is None or hit[0] != key:
            with torch.no_grad():
                hit = (key, self.codec.emulate(lv))
            self._emulated[k] = hit
        return hit[1]

    @property
    def num_levels(self) -> int:
        return len(self.levels)

    def choose_levels(self, lod: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Stochastic level per query: floor(lod) + 1 with probability frac(lod), clamped."""
        lod = lod.clamp(0.0, self.num_levels - 1)
        k = lod.floor()
        k = k + (u < (lod - k)).to(k.dtype)
        return k.clamp(0, self.num_levels - 1).long()

    def tile_index(self, uv: torch.Tensor) -> torch.Tensor:
        """Index [N] into ``tiles`` of each uv's UDIM tile; ``ValueError`` naming the first untrained tile
        (or the uv outside every UDIM tile) when a uv falls outside the trained tiles."""
        udim = udim_of_uv(uv)
        idx = torch.searchsorted(self.tiles, udim).clamp(max=len(self.tiles) - 1)
        bad = self.tiles[idx] != udim
        if bool(bad.any()):
            i = int(torch.nonzero(bad)[0, 0])
            where = f"UDIM tile {int(udim[i])}" if int(udim[i]) > 0 else "no UDIM tile"
            raise ValueError(f"uv ({float(uv[i, 0]):.4g}, {float(uv[i, 1]):.4g}) is in {where}, which this "
                             f"material was not trained on (its tiles: {self.tile_list})")
        return idx

    def fetch(self, uv: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
        """Bilinear latents [N, C] at uv [N,2] from integer ``level`` [N] (0 = finest).

        A uniform material's single 1x1 code is returned as it is, broadcast to the N queries
        (bilinear weights over one texel sum to 1); otherwise each level present in the batch is
        read with :func:`bilinear_periodic`. (A single gather over all levels laid end to end was
        measured slower on the CPU: 14 ms against 11 ms for 65k queries on a 256² pyramid.)
        A UDIM pyramid reads each (tile, level) group with :func:`bilinear_clamp` at ``frac(uv)``.
        """
        if self.tiles is not None:
            return self._fetch_tiled(uv, level)
        if self.num_levels == 1 and tuple(self.levels[0].shape[1:]) == (1, 1):
            return self.level(0).reshape(1, self.channels).expand(uv.shape[0], -1)
        out = torch.zeros(uv.shape[0], self.channels, dtype=self.levels[0].dtype, device=uv.device)
        for k in torch.unique(level).tolist():
            idx = torch.nonzero(level == k)[:, 0]
            out = out.index_put((idx,), bilinear_periodic(self.level(int(k)), uv[idx]))
        return out

    def _fetch_tiled(self, uv: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
        tile = self.tile_index(uv)
        local = uv - torch.floor(uv)
        out = torch.zeros(uv.shape[0], self.channels, dtype=self.levels[0].dtype, device=uv.device)
        key = tile * self.num_levels + level
        for kk in torch.unique(key).tolist():
            t, k = divmod(int(kk), self.num_levels)
            idx = torch.nonzero(key == kk)[:, 0]
            out = out.index_put((idx,), bilinear_clamp(self.level(k)[t], local[idx]))
        return out

    def forward(self, uv: torch.Tensor, lod: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return self.fetch(uv, self.choose_levels(lod, u))
