"""Latent textures: the latent pyramid as 4-channel half-float OpenEXR MIP chains.

Latent channels are grouped by four: texture k holds channels 4k .. 4k+3 as R, G,
B, A; the last texture's unused channels are zero. Each file is a tiled OpenEXR
("Plain Texture", 64x64 tiles, lossless zip) whose MIP levels **are** the pyramid's
levels as trained, not a downsampled level 0: level j is ``levels[j]`` with shape
[C, H_j, W_j], H_j = ceil(H_0 / 2^j) (OpenEXR rounding mode ROUND_UP, which is the
pyramid's halving rule), down to 1x1. Row 0 of an image is its top row, uv (0, 0)
the bottom-left corner (as the pyramid stores it). Wrap modes are periodic, the
colour space is ``raw`` (OpenImageIO 3 stores and reports it as ``data``, its
canonical name for raw), and the values are unitless latent codes.

Values are range-checked before rounding to half (see :mod:`.fp16`); the notes say
what was clamped or kept. Every file is written under a temporary name and renamed.

UDIM materials (:mod:`mtlx2neural.model.latent`: one pyramid per trained tile) write one such
file per channel group *and tile*: ``latents_<k>.<UDIM number>.exr`` (``latents_0.1001.exr``,
``latents_0.1002.exr``, ...), whose wrap modes are ``clamp`` (a tile's latents are read at
``frac(uv)`` clamped to its edges). The paths returned, and referenced from USD, are the
patterns ``latents_<k>.<UDIM>.exr`` with the literal token, as ``UsdUVTexture`` expects; the
tile list itself is in the weights manifest (``architecture.udim_tiles``) and the layer
(``neural:udimTiles``).

A block-compressed pyramid (``TrainConfig.latent_format`` ``bc6h`` or ``bc1``;
:mod:`mtlx2neural.formats.latent_codec`) is written as DDS files instead, ``latents_<k>.dds``
(``latents_<k>.<UDIM>.dds`` per tile), three channels each, the pyramid's levels as the MIP chain.
DDS halves a level's size rounding down, so only a pyramid whose level sizes follow that rule (every
power-of-two grid does) can be written (:func:`~mtlx2neural.formats.latent_codec.check_block_shapes`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import torch

from mtlx2neural.atomic import atomic_path
from mtlx2neural.errors import InputError
from mtlx2neural.formats.fp16 import to_fp16
from mtlx2neural.formats.latent_codec import (
    FORMATS,
    LatentCodec,
    block_texture_names,
    read_block_textures,
    write_block_textures,
)
from mtlx2neural.imaging.mip_chain import read_mip_chain

TILE = 64
COLORSPACE = "raw"


UDIM_TOKEN = "<UDIM>"


def texture_names(channels: int, stem: str = "latents", udim: bool = False, latent_format: str = "exr") -> list[str]:
    """File names of the latent textures, in channel order: ceil(channels / 4) EXRs, or ceil(channels / 3)
    DDS files of a block format (``udim``: the ``<stem>_<k>.<UDIM>.<ext>`` patterns of a UDIM material's
    per-tile files)."""
    if FORMATS[latent_format] is not None:
        return block_texture_names(channels, stem, udim)
    tag = f".{UDIM_TOKEN}" if udim else ""
    return [f"{stem}_{k}{tag}.exr" for k in range(math.ceil(channels / 4))]


def tile_file(pattern, udim: int) -> Path:
    """The file of UDIM tile ``udim`` for a ``<UDIM>`` pattern path."""
    return Path(str(pattern).replace(UDIM_TOKEN, str(int(udim))))


def _spec(width: int, height: int, nchannels: int, wrap: str, colorspace: str, attrs: dict):
    s = oiio.ImageSpec(width, height, nchannels, "half")
    s.tile_width = s.tile_height = TILE
    s.attribute("textureformat", "Plain Texture")  # OpenImageIO writes MIP levels only for textures
    s.attribute("openexr:roundingmode", 1)  # ROUND_UP: level j is ceil(size / 2^j)
    s.attribute("compression", "zip")
    s.attribute("wrapmodes", f"{wrap},{wrap}")
    s.attribute("oiio:ColorSpace", colorspace)
    for key, value in attrs.items():
        s.attribute(key, value)
    return s


def write_mip_chain(path: Path, images: list[np.ndarray], wrap: str = "periodic", colorspace: str = COLORSPACE,
                    attrs: dict | None = None) -> None:
    """Write ``images`` ([H_j, W_j, C] float16, finest first, each level ceil(H_0 / 2^j)) as the MIP levels
    of one tiled half-float EXR at ``path`` (atomically), with ``wrap`` modes, ``colorspace`` and extra
    header ``attrs``."""

    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise OSError(f"{path}: OpenImageIO cannot write OpenEXR ({oiio.geterror()})")
    with atomic_path(path) as tmp:
        for j, img in enumerate(images):
            mode = "AppendMIPLevel" if j else "Create"
            spec = _spec(img.shape[1], img.shape[0], img.shape[2], wrap, colorspace, attrs or {})
            if not out.open(str(tmp), spec, mode):
                raise OSError(f"{path}: cannot open MIP level {j} for writing ({out.geterror()})")
            if not out.write_image(np.ascontiguousarray(img)):
                raise OSError(f"{path}: cannot write MIP level {j} ({out.geterror()})")
        if not out.close():
            raise OSError(f"{path}: cannot finish the file ({out.geterror()})")
        del out  # OpenImageIO flushes a MIP-mapped EXR only when the writer is destroyed


def write_latent_textures(levels: list[torch.Tensor], folder, stem: str = "latents",
                          tiles=None, codec: LatentCodec | None = None) -> tuple[list[Path], list[str]]:
    """Write the pyramid ``levels`` (finest first, each [C, H, W]) into ``folder``; with ``tiles``
    (UDIM numbers) the levels are [T, C, H, W] and each tile gets its own files (module docstring).

    Returns (the written paths in channel order, ``<UDIM>`` patterns for tiles; FP16 range-check notes).
    ``codec``: write the block-compressed DDS files instead (:func:`write_block_textures`; no notes).
    """
    if codec is not None:
        return write_block_textures(levels, codec, folder, stem, tiles), []
    if tiles is not None:
        paths, notes = [], []
        for t, udim in enumerate(tiles):
            written, n = _write_group_files(folder, [lv[t] for lv in levels], stem, f".{int(udim)}", "clamp")
            paths.append(written)
            notes += n
        return [p.parent / p.name.replace(f".{int(tiles[0])}.exr", f".{UDIM_TOKEN}.exr") for p in paths[0]], notes
    return _write_group_files(folder, levels, stem, "", "periodic")


def _write_group_files(folder, levels, stem: str, tag: str, wrap: str) -> tuple[list[Path], list[str]]:
    """One MIP-chain EXR per group of four channels of ``levels`` ([C, H, W] each), named
    ``<stem>_<k><tag>.exr``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    channels = int(levels[0].shape[0])
    notes: list[str] = []
    paths = []
    for k, name in enumerate(f"{n[:-len('.exr')]}{tag}.exr" for n in texture_names(channels, stem)):
        images = []
        for j, lv in enumerate(levels):
            block = lv[4 * k: 4 * k + 4].detach().float().cpu()
            c, h, w = block.shape
            if c < 4:  # pad the last group with zero channels
                block = torch.cat([block, block.new_zeros(4 - c, h, w)])
            half, n = to_fp16(block.permute(1, 2, 0), f"latent texture {name} MIP level {j} "
                                                     f"(channels {4 * k}-{4 * k + c - 1})")
            notes += n
            images.append(half)
        write_mip_chain(folder / name, images, wrap,
                        attrs={"mtlx2neural:latentChannels": f"{4 * k}-{4 * k + 3} of {channels}"})
        paths.append(folder / name)
    return paths, notes


def read_latent_textures(paths, channels: int, tiles=None, codec: LatentCodec | None = None) -> list[torch.Tensor]:
    """The latent pyramid from its textures (in channel order): one float32 [channels, H_j, W_j]
    tensor per MIP level, finest first, holding exactly the stored half values (``codec``: the DDS
    files' decoded values). With ``tiles``
    (UDIM numbers), ``paths`` are ``<UDIM>`` patterns and each level is [T, channels, H_j, W_j],
    tile by tile; a missing tile file is an :class:`InputError` naming it."""
    if tiles is not None:
        per_tile = []
        for udim in tiles:
            files = [tile_file(p, udim) for p in paths]
            for f, p in zip(files, paths):
                if not f.is_file():
                    raise InputError(f"{f}: the latent texture of UDIM tile {udim} ({p}) does not exist; keep the "
                                     f"exported folder complete, or export the material again")
            per_tile.append(read_latent_textures(files, channels, codec=codec))
        if any([lv.shape for lv in t] != [lv.shape for lv in per_tile[0]] for t in per_tile):
            raise InputError(f"{paths[0]}: the UDIM tiles' latent textures differ in size; export the material again")
        return [torch.stack([t[j] for t in per_tile]) for j in range(len(per_tile[0]))]
    if codec is not None:
        return read_block_textures(paths, codec)
    chains = [read_mip_chain(p) for p in paths]
    if not chains or 4 * len(chains) < channels:
        raise InputError(f"{channels} latent channels need {math.ceil(channels / 4)} latent textures, "
                         f"got {len(chains)}: {', '.join(map(str, paths))}")
    n = len(chains[0])
    for p, ch in zip(paths, chains):
        if [c.shape for c in ch] != [c.shape for c in chains[0]]:
            raise InputError(f"{p}: its MIP levels {[c.shape[:2] for c in ch]} differ from {paths[0]}'s "
                             f"{[c.shape[:2] for c in chains[0]]}")
    levels = []
    for j in range(n):
        stacked = np.concatenate([ch[j] for ch in chains], axis=-1)[..., :channels]
        levels.append(torch.from_numpy(stacked.astype(np.float32)).permute(2, 0, 1).contiguous())
    return levels
