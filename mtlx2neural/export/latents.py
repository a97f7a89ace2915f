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
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from mtlx2neural.atomic import atomic_path
from mtlx2neural.errors import InputError
from mtlx2neural.formats.fp16 import to_fp16
from mtlx2neural.imaging.mip_chain import read_mip_chain

TILE = 64
COLORSPACE = "raw"


def texture_names(channels: int, stem: str = "latents") -> list[str]:
    """File names of the ceil(channels / 4) latent textures, in channel order."""
    return [f"{stem}_{k}.exr" for k in range(math.ceil(channels / 4))]


def _spec(width: int, height: int, group: int, channels: int):
    import OpenImageIO as oiio

    s = oiio.ImageSpec(width, height, 4, "half")
    s.tile_width = s.tile_height = TILE
    s.attribute("textureformat", "Plain Texture")  # OpenImageIO writes MIP levels only for textures
    s.attribute("openexr:roundingmode", 1)  # ROUND_UP: level j is ceil(size / 2^j)
    s.attribute("compression", "zip")
    s.attribute("wrapmodes", "periodic,periodic")
    s.attribute("oiio:ColorSpace", COLORSPACE)
    s.attribute("mtlx2neural:latentChannels", f"{4 * group}-{4 * group + 3} of {channels}")
    return s


def _write_mip_chain(path: Path, images: list[np.ndarray], group: int, channels: int) -> None:
    """Write ``images`` ([H_j, W_j, 4] float16, finest first) as the MIP levels of one EXR at ``path``."""
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise OSError(f"{path}: OpenImageIO cannot write OpenEXR ({oiio.geterror()})")
    with atomic_path(path) as tmp:
        for j, img in enumerate(images):
            mode = "AppendMIPLevel" if j else "Create"
            if not out.open(str(tmp), _spec(img.shape[1], img.shape[0], group, channels), mode):
                raise OSError(f"{path}: cannot open MIP level {j} for writing ({out.geterror()})")
            if not out.write_image(np.ascontiguousarray(img)):
                raise OSError(f"{path}: cannot write MIP level {j} ({out.geterror()})")
        if not out.close():
            raise OSError(f"{path}: cannot finish the file ({out.geterror()})")
        del out  # OpenImageIO flushes a MIP-mapped EXR only when the writer is destroyed


def write_latent_textures(levels: list[torch.Tensor], folder, stem: str = "latents") -> tuple[list[Path], list[str]]:
    """Write the pyramid ``levels`` (finest first, each [C, H, W]) into ``folder``.

    Returns (the written paths in channel order, FP16 range-check notes).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    channels = int(levels[0].shape[0])
    notes: list[str] = []
    paths = []
    for k, name in enumerate(texture_names(channels, stem)):
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
        _write_mip_chain(folder / name, images, k, channels)
        paths.append(folder / name)
    return paths, notes


def read_latent_textures(paths, channels: int) -> list[torch.Tensor]:
    """The latent pyramid from its textures (in channel order): one float32 [channels, H_j, W_j]
    tensor per MIP level, finest first, holding exactly the stored half values."""
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
