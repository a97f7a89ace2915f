"""Torch operators for MaterialX's hex-tiling texture nodes ``hextiledimage`` and ``hextilednormalmap``
(Mikkelsen's "Practical Real-Time Hex-Tiling", as MaterialX 1.39 implements it).

The texture coordinate (``texcoord * tiling``, MaterialX's uv: v up) is covered by a grid of hexagonal
tiles: scaled by 2 sqrt(3) and skewed onto a triangle grid, each point lies in one triangle whose three
corners are tile centres, with barycentric weights.  Each tile reads the texture at the coordinate rotated
about its centre (angle within ``rotationrange`` degrees, scaled by ``rotation``), divided by a scale (within
``scalerange``, blended from 1 by ``scale``) and shifted (within ``offsetrange``, times ``offset``); the
three random numbers come from a deterministic hash of the corner's integer grid id (the same float32
arithmetic as MaterialX's, so the tiles match exactly).  The three reads are blended with weights
barycentric^7 (``hextiledimage``: times the reads' luminance, ``lumacoeffs``, contrasted by
``falloffcontrast``), normalised, then sharpened by Schlick's gain ``falloff`` (0.5: unchanged).

``hextiledimage`` returns colour (color3, or color4 whose alpha is blended without the luminance term),
blended from the file's values and then converted from the file's colour space to the working space, as
MaterialX converts the node's output.
``hextilednormalmap`` reads tangent-space normal maps (encoded [0, 1], ``flip_g`` flips green), rotates each
tile's tangent and bitangent about ``normal`` by the tile's angle, scales them by ``strength``, and blends
the three perturbed normals as surface gradients; the result is a unit world-space normal, as ``normalmap``.

Textures are read with periodic addressing and bilinear filtering at full resolution: MaterialX reads them
with ``textureGrad`` over the pixel footprint, which a point sample does not have (the per-point oracle's
derivatives are zero too).  A texture path is resolved when the node first runs (an error names the node).
Values are ``[B, C]`` float32 tensors as in :mod:`mtlx2neural.graph.ops`.
"""

from __future__ import annotations

import math

import torch

from mtlx2neural.graph.ops import EPS, dot, normalize, op, safe_div
from mtlx2neural.graph.spatial import needs_conversion, texture, texture_colorspaces
from mtlx2neural.imaging.colour import convert_torch
from mtlx2neural.imaging.texel_lookup import conform_channels

_FIT = math.sqrt(3.0) * 2.0  # coordinate scale that keeps the tiles' original fit
_SKEW = 1.15470054  # 2 tan(30 deg): height of the skewed triangle grid
_TAN30 = 0.57735027


def _hash2(p: torch.Tensor) -> torch.Tensor:
    """Two pseudo-random numbers in [0, 1) per row of ``p`` [N, 2] (a Dave Hoskins-style fract hash)."""
    x, y = p[:, 0:1], p[:, 1:2]
    a = torch.cat([x * 0.1031, y * 0.1030, x * 0.0973], -1)
    a = a - a.floor()
    shifted = torch.cat([a[:, 1:2], a[:, 2:3], a[:, 0:1]], -1) + 33.33
    a = a + dot(a, shifted)
    r = torch.cat([(a[:, 0:1] + a[:, 1:2]) * a[:, 2:3], (a[:, 0:1] + a[:, 2:3]) * a[:, 1:2]], -1)
    return r - r.floor()


def _tiles(a) -> tuple[torch.Tensor, list[torch.Tensor], torch.Tensor]:
    """(barycentric weights [N, 3], per-tile texture coordinates 3 x [N, 2], per-tile angles [N, 3] in
    radians) of the hex tiling at ``texcoord * tiling``."""
    coord = a["texcoord"] * a["tiling"]
    st = coord * _FIT
    skewed = torch.cat([st[:, 0:1] - _TAN30 * st[:, 1:2], _SKEW * st[:, 1:2]], -1)
    base = skewed.floor()
    frac = skewed - base
    fz = 1.0 - frac[:, 0:1] - frac[:, 1:2]
    upper = (fz <= 0.0).to(coord.dtype)  # the triangle above the cell's diagonal
    sign = 2.0 * upper - 1.0
    weights = torch.cat([-fz * sign, upper - frac[:, 1:2] * sign, upper - frac[:, 0:1] * sign], -1)
    corners = [base + torch.cat([upper, upper], -1), base + torch.cat([upper, 1.0 - upper], -1),
               base + torch.cat([1.0 - upper, upper], -1)]
    lo_rot, hi_rot = torch.deg2rad(a["rotationrange"][:, 0:1]), torch.deg2rad(a["rotationrange"][:, 1:2])
    lo_s, hi_s = a["scalerange"][:, 0:1], a["scalerange"][:, 1:2]
    lo_o, hi_o = a["offsetrange"][:, 0:1], a["offsetrange"][:, 1:2]
    coords, angles = [], []
    for ident in corners:
        q = ident / _FIT
        centre = torch.cat([q[:, 0:1] + 0.5 * q[:, 1:2], q[:, 1:2] / _SKEW], -1)
        rnd = _hash2(ident + 0.12345)
        angle = lo_rot + (hi_rot - lo_rot) * (rnd[:, 0:1] * a["rotation"])
        scale = 1.0 + ((lo_s + (hi_s - lo_s) * rnd[:, 1:2]) - 1.0) * a["scale"]
        shift = lo_o + (hi_o - lo_o) * (rnd * a["offset"])
        d = coord - centre
        c, s = angle.cos(), angle.sin()
        turned = torch.cat([d[:, 0:1] * c - d[:, 1:2] * s, d[:, 0:1] * s + d[:, 1:2] * c], -1)
        coords.append(turned / scale + centre + shift)
        angles.append(angle)
    return weights, coords, torch.cat(angles, -1)


def _gain(x: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """Schlick's gain of ``x`` in [0, 1] with parameter ``r`` (clamped to [0.001, 0.999]; 0.5: identity)."""
    r = r.clamp(0.001, 0.999)
    k = (1.0 / r - 2.0) * (1.0 - 2.0 * x)
    return torch.where(x < 0.5, x / (k + 1.0), safe_div(k - x, k - 1.0))


def _blend_weights(lum: torch.Tensor, bary: torch.Tensor, falloff: torch.Tensor) -> torch.Tensor:
    """Normalised blend weights [N, 3]: lum * bary^7, then Schlick's gain by ``falloff`` unless it is 0.5."""
    w = lum * bary.pow(7)
    w = safe_div(w, w.sum(-1, keepdim=True))
    sharp = _gain(w, falloff)
    sharp = safe_div(sharp, sharp.sum(-1, keepdim=True))
    return torch.where(falloff != 0.5, sharp, w)


def _reads(a, n, coords: list[torch.Tensor], channels: int) -> list[torch.Tensor] | None:
    """The texture at each tile's coordinates ([N, channels] each), or None when the node has no file."""
    path = a["file"]
    if not path or n.attrs.get("missing"):
        return None
    tex = texture(path, n.path)
    border = conform_channels(a["default"], tex.channels)
    return [conform_channels(tex.sample(uv, default=border), channels) for uv in coords]


def _to_working_space(value: torch.Tensor, n) -> torch.Tensor:
    """The blended colour converted from the file's colour space to the working space (MaterialX converts
    the node's output, so the blend and its luminance weights use the file's values)."""
    src, dst = texture_colorspaces(n)
    if not needs_conversion(src, dst):
        return value
    return torch.cat([convert_torch(value[:, :3], src, dst), value[:, 3:]], -1)


@op("hextiledimage")
def _hextiledimage(a, n):
    """Hex-tiled colour [N, 3] or [N, 4] (see the module docstring); ``default`` without a file."""
    channels = 4 if n.type == "color4" else 3
    bary, coords, _ = _tiles(a)
    reads = _reads(a, n, coords, channels)
    if reads is None:
        return a["default"].expand(bary.shape[0], -1)
    lum = torch.cat([dot(c[:, :3], a["lumacoeffs"]) for c in reads], -1)
    lum = 1.0 + (lum - 1.0) * a["falloffcontrast"]
    w = _blend_weights(lum, bary, a["falloff"])
    rgb = sum(w[:, k:k + 1] * reads[k][:, :3] for k in range(3))
    if channels == 3:
        return _to_working_space(rgb, n)
    aw = _blend_weights(torch.ones_like(bary), bary, a["falloff"])
    alpha = sum(aw[:, k:k + 1] * reads[k][:, 3:4] for k in range(3))
    return _to_working_space(torch.cat([rgb, alpha], -1), n)


def _turn(v: torch.Tensor, axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """``v`` rotated by ``angle`` (radians, counter-clockwise seen from the tip of unit ``axis``)."""
    c, s = angle.cos(), angle.sin()
    cross = torch.linalg.cross(*torch.broadcast_tensors(axis, v), dim=-1)
    return v * c + cross * s + axis * dot(axis, v) * (1.0 - c)


@op("hextilednormalmap")
def _hextilednormalmap(a, n):
    """Hex-tiled normal map: a unit world-space normal [N, 3] (see the module docstring); without a file,
    each tile reads ``default``."""
    bary, coords, angles = _tiles(a)
    rows = bary.shape[0]
    reads = _reads(a, n, coords, 3) or [a["default"].expand(rows, 3)] * 3
    nrm, tan, bit = a["normal"], a["tangent"], a["bitangent"]
    flip = a["flip_g"]
    flip = flip if isinstance(flip, torch.Tensor) else torch.tensor([[float(bool(flip))]])
    normals = []
    for k, m in enumerate(reads):
        g = torch.where(flip.to(m.device) > 0.5, 1.0 - m[:, 1:2], m[:, 1:2])
        m = torch.cat([m[:, 0:1], g, m[:, 2:3]], -1) * 2.0 - 1.0
        t = _turn(tan, nrm, angles[:, k:k + 1]) * a["strength"]
        b = _turn(bit, nrm, angles[:, k:k + 1]) * a["strength"]
        normals.append(normalize(t * m[:, 0:1] + b * m[:, 1:2] + nrm * m[:, 2:3]))
    w = _blend_weights(torch.ones_like(bary), bary, a["falloff"]).clamp(0.0, 1.0)
    grad = 0
    for k, nk in enumerate(normals):
        d = dot(nrm, nk)
        grad = grad + w[:, k:k + 1] * (d * nrm - nk) / d.abs().clamp_min(EPS)
    return normalize(nrm - grad)
