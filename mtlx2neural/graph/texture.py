"""Minimal texture lookups for the spatial sub-graph (image node).

Files are read once with OpenImageIO into float32 tensors and sampled
bilinearly with MaterialX's conventions: uv (0,0) is the image's bottom-left
corner, address modes periodic/clamp/mirror/constant. Colour management is
limited to the sRGB texture transfer function here; the textures stage does
full OpenColorIO conversion.
"""

from __future__ import annotations

import functools
import os

import torch

from ..errors import InputError


@functools.lru_cache(maxsize=64)
def _load(path: str) -> torch.Tensor:
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise InputError(f"cannot read texture '{path}': {oiio.geterror()}")
    try:
        pixels = inp.read_image(0, 0, 0, inp.spec().nchannels, "float")
    finally:
        inp.close()
    if pixels is None:
        raise InputError(f"cannot decode texture '{path}'.")
    t = torch.from_numpy(pixels.copy()).float()
    return t if t.dim() == 3 else t[..., None]


def check_texture(path: str, node_path: str, source: str) -> None:
    """Raise InputError naming the file and node when a texture is missing."""
    if "<UDIM>" in path or "<UVTILE>" in path:
        return
    if not os.path.isfile(path):
        raise InputError(f"{source}: texture file '{path}' used by node '{node_path}' does not exist. "
                         f"Fix the path or provide the file.")


def _address(coord: torch.Tensor, size: int, mode: str):
    """Integer texel indices for ``coord`` (texel units) under a MaterialX address mode."""
    if mode == "clamp" or mode == "constant":
        return coord.clamp(0, size - 1)
    if mode == "mirror":
        period = 2 * size
        c = torch.remainder(coord, period)
        return torch.where(c >= size, period - 1 - c, c)
    return torch.remainder(coord, size)


def sample_image(path: str, uv: torch.Tensor, umode: str, vmode: str, channels: int,
                 default: torch.Tensor, srgb: bool) -> torch.Tensor:
    """Bilinear lookup ``[N, channels]`` at ``uv`` [N,2]."""
    tex = _load(path).to(uv.device)
    h, w, c = tex.shape
    x = uv[:, 0] * w - 0.5
    y = (1.0 - uv[:, 1]) * h - 0.5
    x0, y0 = x.floor(), y.floor()
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.long(), y0.long()
    out = 0
    for dx, dy, wgt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        xi, yi = _address(x0 + dx, w, umode), _address(y0 + dy, h, vmode)
        out = out + tex[yi, xi] * wgt
    if srgb:
        rgb = out[:, :3]
        out = torch.cat([torch.where(rgb <= 0.04045, rgb / 12.92, ((rgb.clamp_min(0) + 0.055) / 1.055) ** 2.4),
                         out[:, 3:]], -1)
    if c < channels:
        fill = out[:, :1].expand(-1, channels) if c == 1 else torch.cat(
            [out, torch.ones(out.shape[0], channels - c, dtype=out.dtype, device=out.device)], -1)
        out = fill
    out = out[:, :channels]
    outside = torch.zeros_like(uv[:, 0], dtype=torch.bool)
    if umode == "constant":
        outside |= (uv[:, 0] < 0) | (uv[:, 0] > 1)
    if vmode == "constant":
        outside |= (uv[:, 1] < 0) | (uv[:, 1] > 1)
    return torch.where(outside[:, None], default.expand_as(out), out)
