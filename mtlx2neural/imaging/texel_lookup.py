"""Texel lookups with MaterialX address modes and filters, on images ``[H, W, C]`` (row 0 = top).

Coordinates: uv ``(0, 0)`` is the image's bottom-left corner and ``(1, 1)`` its
top-right; in texel units ``x = u * W`` and ``y = (1 - v) * H`` with texel
``(i, j)`` covering ``[i, i+1) x [j, j+1)``, its centre at ``(i + 0.5, j + 0.5)``.
All functions are batched over ``[N]`` samples, torch only, on any device.
"""

from __future__ import annotations

import torch

ADDRESS_MODES = ("constant", "clamp", "periodic", "mirror")
"""MaterialX ``uaddressmode`` / ``vaddressmode`` values."""

FILTER_TYPES = ("closest", "linear", "cubic")
"""MaterialX ``filtertype`` values."""


def _address_texel(i: torch.Tensor, size: int, mode: str) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Integer texel index under an address mode, and for ``constant`` the mask of taps inside the image.

    ``constant`` taps outside the image read the border (default) value, like a GPU
    sampler in CLAMP_TO_BORDER mode with the default as border colour.
    """
    if mode == "periodic":
        return torch.remainder(i, size), None
    if mode == "mirror":  # GL_MIRRORED_REPEAT: ... 1 0 | 0 1 ... n-1 | n-1 n-2 ...
        c = torch.remainder(i, 2 * size)
        return torch.where(c >= size, 2 * size - 1 - c, c), None
    inside = ((i >= 0) & (i < size)) if mode == "constant" else None
    return i.clamp(0, size - 1), inside


def address_coord(x: torch.Tensor, lo: float, hi: float, mode: str) -> torch.Tensor:
    """A continuous coordinate folded into ``[lo, hi]`` by ``periodic`` / ``mirror``.

    ``clamp`` and ``constant`` leave it unchanged: their clamping happens per
    filter tap (clamp-to-edge, as OpenImageIO and GPU samplers do), which for a
    cubic filter differs from clamping the coordinate itself.
    """
    w = hi - lo
    if mode == "periodic":
        return lo + torch.remainder(x - lo, w)
    if mode == "mirror":
        m = torch.remainder(x - lo, 2 * w)
        return lo + torch.where(m > w, 2 * w - m, m)
    return x


def _bspline_weights(t: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """Uniform cubic B-spline weights of the taps at -1, 0, +1, +2 for fraction ``t`` in [0, 1]."""
    t2, t3 = t * t, t * t * t
    s = 1.0 - t
    return (s * s * s / 6.0, (3 * t3 - 6 * t2 + 4) / 6.0, (-3 * t3 + 3 * t2 + 3 * t + 1) / 6.0, t3 / 6.0)


def _taps(x: torch.Tensor, size: int, mode: str, filtertype: str):
    """``[(index, inside mask or None, weight or None)]`` along one axis; ``x`` in texel units."""
    if filtertype == "closest":
        return [(*_address_texel(x.floor().long(), size, mode), None)]
    xf = x - 0.5
    x0 = xf.floor()
    t = xf - x0
    i0 = x0.long()
    weights = (1.0 - t, t) if filtertype == "linear" else _bspline_weights(t)
    first = 0 if filtertype == "linear" else -1
    return [(*_address_texel(i0 + first + k, size, mode), wk) for k, wk in enumerate(weights)]


def sample_image(img: torch.Tensor, u: torch.Tensor, v: torch.Tensor, umode: str, vmode: str,
                 filtertype: str, border: torch.Tensor | None = None, scale: float = 1.0) -> torch.Tensor:
    """Filter ``img`` ``[H, W, C]`` (row 0 = top) at uv ``[N]`` (bottom-left origin) -> ``[N, C]`` float32.

    ``img`` may be stored as integers or half floats: each gathered texel is
    converted to float32 and multiplied by ``scale`` (1/255 for 8-bit data).

    Address modes apply per filter tap. Taps outside the image along a
    ``constant`` axis read ``border`` (``[N, C]``, zeros when None); the caller
    decides what to return for uv outside [0, 1] itself.
    """
    h, w, c = img.shape
    flat = img.reshape(h * w, c)
    tx = _taps(u * w, w, umode, filtertype)
    ty = _taps((1.0 - v) * h, h, vmode, filtertype)
    out = None
    for iy, my, wy in ty:
        for ix, mx, wx in tx:
            val = flat[iy * w + ix]
            if val.dtype != torch.float32 and val.dtype != torch.float64:
                val = val.float() * scale if scale != 1.0 else val.float()
            mask = my if mx is None else (mx if my is None else mx & my)
            if mask is not None:
                fill = border if border is not None else torch.zeros_like(val)
                val = torch.where(mask[:, None], val, fill)
            if wx is not None:
                val = val * (wx * wy).to(val.dtype)[:, None]
            out = val if out is None else out + val
    return out


def finite_texels(img: torch.Tensor) -> torch.Tensor:
    """Sampling copy of texels with NaN -> 0 and +-Inf -> +-65504 (the largest half); no copy when all finite."""
    if bool(torch.isfinite(img).all()):
        return img
    return torch.nan_to_num(img, nan=0.0, posinf=65504.0, neginf=-65504.0)


def conform_channels(img: torch.Tensor, channels: int) -> torch.Tensor:
    """Give ``img`` ``channels`` channels: grey broadcasts to RGB, missing channels (alpha) are 1."""
    c = img.shape[-1]
    if c == channels:
        return img
    if c > channels:
        return img[..., :channels]
    if c == 1:
        img = img.expand(*img.shape[:-1], min(channels, 3))
    if img.shape[-1] < channels:
        ones = torch.ones(*img.shape[:-1], channels - img.shape[-1], dtype=img.dtype, device=img.device)
        img = torch.cat([img, ones], -1)
    return img.contiguous()
