"""BC1 (DXGI_FORMAT_BC1_UNORM) codec for opaque 3-channel data, with a differentiable torch emulation.

Layout and conventions
----------------------
- An image is ``[H, W, 3]`` (NumPy) or ``[3, H, W]`` (torch) with values in [0, 1]; values outside
  are clamped and NaN is read as 0. Row 0 is the top row. Partial blocks are padded by edge
  replication (the padded texels take part in the fit and are dropped on decode).
- 4x4 blocks are stored row-major (block rows top to bottom, left to right), 8 bytes each:
  ``color0`` (uint16 LE), ``color1`` (uint16 LE), then a uint32 LE of 2-bit indices where texel
  ``(x, y)`` of the block uses bits ``2*(4*y + x)``. Colours are RGB565: R in bits 15-11,
  G in bits 10-5, B in bits 4-0.
- Palette (the decoder, :func:`decode`): endpoints are expanded to 8 bits by bit replication
  (``r8 = r5 << 3 | r5 >> 2``, ``g8 = g6 << 2 | g6 >> 4``). If ``color0 > color1`` (4-colour mode)
  ``p2 = (2*c0 + c1) // 3`` and ``p3 = (c0 + 2*c1) // 3``; otherwise (3-colour mode, only read,
  never written) ``p2 = (c0 + c1) // 2`` and ``p3 = 0`` (black; alpha is ignored). A texel's value
  is ``p / 255`` as float32.
- Why 8-bit integers with truncation (not rounding, not float): it is what the software decoders
  do that this module is checked against bit-exactly (texture2ddecoder; rgbcx calls it the "ideal"
  mode, after the D3D10 BC1 description), so the decoder has an independent exact reference, and
  the training target is a real decoder's output. GPUs use their own approximations of the 1/3,
  2/3 blend (vendors differ; D3D allows a tolerance): entries 2 and 3 may read up to about 1/255
  off on hardware, the endpoints (entries 0 and 1) are exact everywhere.
- The encoder always emits the 4-colour mode (``color0 > color1``). When the two quantised
  endpoints are equal, every index is 0, so the block decodes to ``color0`` in either mode.

The encoder fit (:func:`_fit`) is torch code shared by :func:`encode` and :func:`emulate`, so
``emulate(x)`` equals ``decode(encode(x))`` exactly (on the same device; the fit runs in float32).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

BYTES_PER_BLOCK = 8
"""Bytes per 4x4 block (0.5 byte per texel)."""
CHANNELS = 3
"""Channels per BC1 texture."""
DXGI_UNORM = 71
"""DXGI_FORMAT_BC1_UNORM."""

_BLOCK_DTYPE = np.dtype([("c0", "<u2"), ("c1", "<u2"), ("idx", "<u4")])
_REFITS = 2
_WEIGHT0 = (1.0, 0.0, 2.0 / 3.0, 1.0 / 3.0)
"""Weight of ``color0`` in palette entries 0..3 (4-colour mode), used by the least-squares fit."""


def _column(values, like: torch.Tensor) -> torch.Tensor:
    """Per-channel constants as a ``[3, 1]`` tensor on ``like``'s device."""
    return torch.tensor(values, device=like.device)[:, None]


def _expand(q: torch.Tensor) -> torch.Tensor:
    """5/6/5-bit endpoint values ``[3, N]`` (int64) -> 8 bits by bit replication."""
    return (q << _column([3, 2, 3], q)) | (q >> _column([2, 4, 2], q))


def _pack(q: torch.Tensor) -> torch.Tensor:
    """``[3, N]`` 5/6/5-bit values -> ``[N]`` RGB565 integers."""
    return (q[0] << 11) | (q[1] << 5) | q[2]


def _unpack(c: torch.Tensor) -> torch.Tensor:
    """``[N]`` RGB565 integers -> ``[3, N]`` 5/6/5-bit values."""
    return torch.stack([(c >> 11) & 31, (c >> 5) & 63, c & 31])


def _palette(q0: torch.Tensor, q1: torch.Tensor) -> torch.Tensor:
    """The decoder palette ``[3, N, 4]`` float32 in [0, 1] of endpoints ``q0, q1`` ``[3, N]`` (5/6/5 bits)."""
    c0, c1 = _expand(q0), _expand(q1)
    four = _pack(q0) > _pack(q1)
    p2 = torch.where(four, (2 * c0 + c1) // 3, (c0 + c1) // 2)
    p3 = torch.where(four, (c0 + 2 * c1) // 3, torch.zeros_like(c0))
    return torch.stack([c0, c1, p2, p3], dim=-1).float() / 255.0


def _lookup(pal: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """Texels ``[3, N, 16]`` of palette ``[3, N, 4]`` at indices ``[N, 16]``."""
    return pal.gather(2, idx.expand(3, -1, -1))


def _quantise(e: torch.Tensor) -> torch.Tensor:
    """Endpoints ``[3, N]`` in [0, 1] -> the 5/6/5-bit values whose expanded 8-bit value is nearest."""
    m = _column([31, 63, 31], e)
    lo = torch.minimum(torch.floor(e * m).long(), m)
    hi = torch.minimum(lo + 1, m)
    err_lo = (_expand(lo).float() - e * 255.0).abs()
    err_hi = (_expand(hi).float() - e * 255.0).abs()
    return torch.where(err_hi < err_lo, hi, lo)


def _candidate(x: torch.Tensor, e0: torch.Tensor, e1: torch.Tensor):
    """Quantise endpoints ``[3, N]``, order them for the 4-colour mode and index each texel of ``x``
    ``[3, N, 16]`` to the nearest palette entry (the first on a tie). Returns ``(q0, q1, indices
    [N, 16], squared error minus the constant sum |x|^2 [N])``."""
    q0, q1 = _quantise(e0.clamp(0, 1)), _quantise(e1.clamp(0, 1))
    swap = _pack(q0) < _pack(q1)
    q0, q1 = torch.where(swap, q1, q0), torch.where(swap, q0, q1)
    pal = _palette(q0, q1)
    # |x - p|^2 - |x|^2 per entry, then the first minimum by pairwise comparison; per-channel
    # products, minimum() and integer arithmetic instead of argmin / where, which are slow on CPU
    norm2 = (pal * pal).sum(0)  # [N, 4]
    s = [norm2[:, k, None] - 2.0 * (pal[0, :, k, None] * x[0] + pal[1, :, k, None] * x[1]
                                    + pal[2, :, k, None] * x[2]) for k in range(4)]  # 4 x [N, 16]
    lo, hi = (s[1] < s[0]).long(), (s[3] < s[2]).long()
    s01, s23 = torch.minimum(s[0], s[1]), torch.minimum(s[2], s[3])
    idx = lo + (s23 < s01).long() * (2 + hi - lo)
    equal = _pack(q0) == _pack(q1)  # one colour: every index 0 decodes to it in either mode
    idx = idx * (~equal).long()[:, None]
    score = torch.where(equal, s[0].sum(-1), torch.minimum(s01, s23).sum(-1))
    return q0, q1, idx, score


def _least_squares(x: torch.Tensor, idx: torch.Tensor):
    """Continuous endpoints ``(e0, e1)`` ``[3, N]`` minimising the squared error of blocks ``x``
    ``[3, N, 16]`` given the indices ``[N, 16]``, and the fitted texels ``[3, N, 16]``: the orthogonal
    projection of each block channel onto ``span{1, w}``, ``w`` the weight of ``color0`` per texel.
    Differentiable in ``x``. When all weights are equal the fit is the block mean (both endpoints)."""
    w = torch.tensor(_WEIGHT0, dtype=x.dtype, device=x.device)[idx]  # [N, 16]
    wm = w.mean(-1, keepdim=True)
    wc = w - wm
    den = (wc * wc).sum(-1, keepdim=True)
    ok = den > 0
    xm = x.mean(-1, keepdim=True)
    slope = torch.where(ok, (wc * (x - xm)).sum(-1, keepdim=True) / torch.where(ok, den, 1.0), 0.0)
    return (xm + (1 - wm) * slope)[..., 0], (xm - wm * slope)[..., 0], xm + wc * slope


def _principal_endpoints(x: torch.Tensor):
    """Endpoints ``[3, N]`` at the extreme projections of the texels of ``x`` ``[3, N, 16]`` on the
    block's principal axis (power iteration on the 3x3 covariance, elementwise over blocks)."""
    mean = x.mean(-1, keepdim=True)
    d = x - mean
    cov = (d[:, None] * d[None]).sum(-1)  # [3, 3, N]
    k = torch.diagonal(cov).argmax(-1)  # [N]
    v = cov.gather(1, k.expand(3, 1, -1))[:, 0]  # a column of cov: never orthogonal to the axis
    for _ in range(8):
        v = (cov * v[None]).sum(1)
        v = v / (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().clamp_min(1e-30)
    t = (d * v[..., None]).sum(0)  # [N, 16]
    return mean[..., 0] + v * t.max(-1).values, mean[..., 0] + v * t.min(-1).values


@torch.no_grad()
def _fit(x: torch.Tensor):
    """The encoder on blocks ``x`` ``[3, N, 16]`` float32 in [0, 1]: principal axis + min/max, then
    ``_REFITS`` least-squares refits given the indices, keeping each block's best candidate.
    Returns ``(q0, q1, indices)``."""
    best = _candidate(x, *_principal_endpoints(x))
    for _ in range(_REFITS):
        e0, e1, _ = _least_squares(x, best[2])
        cand = _candidate(x, e0, e1)
        better = cand[3] < best[3]
        best = (torch.where(better, cand[0], best[0]), torch.where(better, cand[1], best[1]),
                best[2] + better.long()[:, None] * (cand[2] - best[2]), torch.where(better, cand[3], best[3]))
    return best[:3]


def _to_blocks(x: torch.Tensor) -> torch.Tensor:
    """``[3, H, W]`` -> ``[3, N, 16]`` blocks (row-major), padded by edge replication."""
    _, h, w = x.shape
    hb, wb = -(-h // 4), -(-w // 4)
    x = F.pad(x[None], (0, 4 * wb - w, 0, 4 * hb - h), mode="replicate")[0]
    return x.reshape(3, hb, 4, wb, 4).transpose(2, 3).reshape(3, hb * wb, 16)


def _from_blocks(b: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """``[3, N, 16]`` blocks -> ``[3, H, W]``, dropping the padding."""
    hb, wb = -(-h // 4), -(-w // 4)
    return b.reshape(3, hb, wb, 4, 4).transpose(2, 3).reshape(3, 4 * hb, 4 * wb)[:, :h, :w]


def _prepare(x: torch.Tensor) -> torch.Tensor:
    """The value the encoder sees: float32, NaN -> 0, clamped to [0, 1] (differentiable)."""
    return torch.nan_to_num(x.float(), nan=0.0).clamp(0.0, 1.0)


def encode(image: np.ndarray) -> bytes:
    """Compress ``image`` ``[H, W, 3]`` (any H, W >= 1; clamped to [0, 1]) to BC1 blocks (module docstring)."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != CHANNELS or image.shape[0] < 1 or image.shape[1] < 1:
        raise ValueError(f"BC1 encode wants an [H, W, 3] image, got shape {image.shape}")
    x = _prepare(torch.from_numpy(np.ascontiguousarray(image, np.float32)).permute(2, 0, 1))
    q0, q1, idx = _fit(_to_blocks(x))
    out = np.empty(len(idx), _BLOCK_DTYPE)
    out["c0"] = _pack(q0).numpy()
    out["c1"] = _pack(q1).numpy()
    out["idx"] = (idx << (2 * torch.arange(16))).sum(-1).numpy()
    return out.tobytes()


def decode(data: bytes, height: int, width: int) -> np.ndarray:
    """Decompress BC1 ``data`` of a ``height`` x ``width`` image to ``[H, W, 3]`` float32 in [0, 1]."""
    if height < 1 or width < 1:
        raise ValueError(f"BC1 decode wants a size >= 1x1, got {height}x{width}")
    n = -(-height // 4) * -(-width // 4)
    if len(data) != n * BYTES_PER_BLOCK:
        raise ValueError(f"BC1 {height}x{width} needs {n * BYTES_PER_BLOCK} bytes, got {len(data)}")
    blocks = np.frombuffer(data, _BLOCK_DTYPE)
    q0 = _unpack(torch.from_numpy(blocks["c0"].astype(np.int64)))
    q1 = _unpack(torch.from_numpy(blocks["c1"].astype(np.int64)))
    idx = (torch.from_numpy(blocks["idx"].astype(np.int64))[:, None] >> (2 * torch.arange(16))) & 3
    texels = _lookup(_palette(q0, q1), idx)
    return _from_blocks(texels, height, width).permute(1, 2, 0).contiguous().numpy()


def emulate(x: torch.Tensor) -> torch.Tensor:
    """BC1 round trip of ``x`` ``[3, H, W]`` (any float dtype and device), differentiable.

    Forward: exactly ``decode(encode(x))`` (as float32, then cast to ``x.dtype``). Backward: the
    indices are chosen without gradient; the gradient is that of the continuous least-squares
    reconstruction given those indices, i.e. for each block and channel the upstream gradient is
    projected orthogonally onto ``span{1, w}`` over the block's 16 texels (``w`` the weight of
    ``color0`` per texel; just the block mean when all indices are equal). Endpoint quantisation to
    565, the 8-bit palette truncation and the choice of the kept candidate are straight-through;
    the input clamp to [0, 1] keeps its true gradient (0 outside), and edge-replicated padding
    sends its share back to the edge texels.
    """
    if x.dim() != 3 or x.shape[0] != CHANNELS:
        raise ValueError(f"BC1 emulate wants a [3, H, W] tensor, got shape {tuple(x.shape)}")
    _, h, w = x.shape
    blocks = _to_blocks(_prepare(x))
    q0, q1, idx = _fit(blocks.detach())
    exact = _lookup(_palette(q0, q1), idx)
    fitted = _least_squares(blocks, idx)[2]
    out = exact + (fitted - fitted.detach())  # value: exact (x - x == 0); gradient: the projection
    return _from_blocks(out, h, w).to(x.dtype)
