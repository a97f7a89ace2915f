"""Torch operators for MaterialX's procedural noise nodes, bit-compatible with its shader code.

MaterialX's noises (from Open Shading Language) are deterministic: lattice points are hashed with Bob
Jenkins' lookup3 mixing functions on 32-bit unsigned integers, Perlin noise takes gradients chosen by
the hash with a quintic fade, cellular noise maps the hash to [0, 1], and Worley noise searches the 3x3
(or 3x3x3) neighbouring cells for jittered feature points. This module re-implements that arithmetic in
torch: unsigned 32-bit wraparound is modelled with int64 tensors masked by ``& 0xFFFFFFFF``, and every
float operation is float32 in the shader's order, so results match MaterialX's generated code to float
rounding (the only differences are the last bits of a few operations, and Worley noise, whose nearest
feature point can change where two distances tie).

Registered categories: noise2d, noise3d, fractal2d, fractal3d, cellnoise2d, cellnoise3d, worleynoise2d,
worleynoise3d. Every output type is handled here (float, vector2/3/4, color3/4, and the "FA" variants with
a float amplitude); unifiednoise2d/3d, randomfloat and randomcolor expand through MaterialX's library
nodegraphs into these operators.
"""

from __future__ import annotations

import torch

from mtlx2neural.graph.ir import CHANNELS
from mtlx2neural.graph.ops import op

MASK = 0xFFFFFFFF
_F32 = torch.float32


def _u32(x: torch.Tensor) -> torch.Tensor:
    return x & MASK


def _rotl(x: torch.Tensor, k: int) -> torch.Tensor:
    """Rotate the 32-bit unsigned ``x`` (int64 holding [0, 2^32)) left by ``k`` bits."""
    return ((x << k) | (x >> (32 - k))) & MASK


def _mix(a, b, c):
    """lookup3's reversible mixing of three 32-bit words (the shader's ``bjmix``)."""
    a = _u32(a - c); a = a ^ _rotl(c, 4); c = _u32(c + b)  # noqa: E702
    b = _u32(b - a); b = b ^ _rotl(a, 6); a = _u32(a + c)  # noqa: E702
    c = _u32(c - b); c = c ^ _rotl(b, 8); b = _u32(b + a)  # noqa: E702
    a = _u32(a - c); a = a ^ _rotl(c, 16); c = _u32(c + b)  # noqa: E702
    b = _u32(b - a); b = b ^ _rotl(a, 19); a = _u32(a + c)  # noqa: E702
    c = _u32(c - b); c = c ^ _rotl(b, 4); b = _u32(b + a)  # noqa: E702
    return a, b, c


def _final(a, b, c):
    """lookup3's final avalanche of three 32-bit words; returns the last word (the hash)."""
    for x, y, k in (("c", "b", 14), ("a", "c", 11), ("b", "a", 25), ("c", "b", 16), ("a", "c", 4),
                    ("b", "a", 14), ("c", "b", 24)):
        w = {"a": a, "b": b, "c": c}
        new = _u32((w[x] ^ w[y]) - _rotl(w[y], k))
        if x == "a":
            a = new
        elif x == "b":
            b = new
        else:
            c = new
    return c


def _seed(n_words: int) -> int:
    return (0xDEADBEEF + (n_words << 2) + 13) & MASK


def hash_ints(*xs: torch.Tensor) -> torch.Tensor:
    """32-bit hash (int64 in [0, 2^32)) of 1 to 3 signed integer lattice coordinates (int64 tensors),
    as the shader's ``mx_hash_int``."""
    s = _seed(len(xs))
    words = [_u32(s + x) for x in xs] + [torch.full_like(xs[0], s)] * (3 - len(xs))
    return _final(*words)


def _bits_to_01(h: torch.Tensor) -> torch.Tensor:
    # float(uint) rounds to float32 first; 0xffffffff rounds to 2^32, so the division is exact.
    return h.to(_F32) / 4294967296.0


def _floorfrac(x: torch.Tensor):
    """(integer lattice coordinate as int64, fractional part as float32)."""
    f = torch.floor(x)
    return f.to(torch.int64), x - f


def _fade(t):
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


def _negate_if(v, bit):
    return torch.where(bit != 0, -v, v)


def _grad2(h, x, y):
    h = h & 7
    low = h < 4
    u = torch.where(low, x, y)
    v = 2.0 * torch.where(low, y, x)
    return _negate_if(u, h & 1) + _negate_if(v, h & 2)


def _grad3(h, x, y, z):
    h = h & 15
    u = torch.where(h < 8, x, y)
    v = torch.where(h < 4, y, torch.where((h == 12) | (h == 14), x, z))
    return _negate_if(u, h & 1) + _negate_if(v, h & 2)


def _bilerp(v0, v1, v2, v3, s, t):
    s1 = 1.0 - s
    return (1.0 - t) * (v0 * s1 + v1 * s) + t * (v2 * s1 + v3 * s)


def _trilerp(v, s, t, r):
    s1, t1, r1 = 1.0 - s, 1.0 - t, 1.0 - r
    return (r1 * (t1 * (v[0] * s1 + v[1] * s) + t * (v[2] * s1 + v[3] * s))
            + r * (t1 * (v[4] * s1 + v[5] * s) + t * (v[6] * s1 + v[7] * s)))


def _split3(h):
    """The three low bytes of a hash: one gradient choice per channel."""
    return [h & 0xFF, (h >> 8) & 0xFF, (h >> 16) & 0xFF]


def perlin(p: torch.Tensor, channels: int) -> torch.Tensor:
    """Perlin gradient noise of points ``p`` [N,2] or [N,3] (float32): ``channels`` 1 -> [N,1], 3 -> [N,3]
    (three noises from one hash, byte per channel). Range roughly [-1, 1]."""
    dims = p.shape[-1]
    ints, fracs = zip(*(_floorfrac(p[:, k]) for k in range(dims)))
    fades = [_fade(f) for f in fracs]
    corners = [(i & 1, (i >> 1) & 1, (i >> 2) & 1)[:dims] for i in range(1 << dims)]
    grad = _grad2 if dims == 2 else _grad3
    scale = 0.6616 if dims == 2 else 0.9820
    out = []
    for ch in range(channels):
        vals = []
        for c in corners:
            h = hash_ints(*(ints[k] + c[k] for k in range(dims)))
            if channels == 3:
                h = _split3(h)[ch]
            vals.append(grad(h, *(fracs[k] - float(c[k]) for k in range(dims))))
        v = _bilerp(*vals, *fades) if dims == 2 else _trilerp(vals, *fades)
        out.append(scale * v)
    return torch.stack(out, -1)


def cell_noise(p: torch.Tensor) -> torch.Tensor:
    """Cellular noise [N,1] in [0, 1]: the hash of floor(p) for ``p`` [N,2] or [N,3]."""
    ints = [torch.floor(p[:, k]).to(torch.int64) for k in range(p.shape[-1])]
    return _bits_to_01(hash_ints(*ints))[:, None]


def cell_noise3(p: torch.Tensor) -> torch.Tensor:
    """Three cellular noises [N,3] in [0, 1] of floor(p), ``p`` [N,2] or [N,3] (as the shader's
    ``mx_cell_noise_vec3``)."""
    ints = [torch.floor(p[:, k]).to(torch.int64) for k in range(p.shape[-1])]
    if len(ints) == 2:
        return torch.stack([_bits_to_01(hash_ints(ints[0], ints[1], torch.full_like(ints[0], k)))
                            for k in range(3)], -1)
    s = _seed(4)
    a, b, c = _mix(*(_u32(s + x) for x in ints))
    return torch.stack([_bits_to_01(_final(_u32(a + k), b, c)) for k in range(3)], -1)


def fractal(p: torch.Tensor, channels: int, octaves, lacunarity, diminish) -> torch.Tensor:
    """Sum of ``octaves`` Perlin octaves (``channels`` 1 or 3), each ``lacunarity`` times the frequency and
    ``diminish`` times the amplitude of the last. ``octaves`` [B,1] may vary per point."""
    result = torch.zeros(p.shape[0], channels, dtype=p.dtype, device=p.device)
    amplitude = torch.ones(1, 1, dtype=p.dtype, device=p.device)
    octaves = octaves.reshape(-1, 1)
    for i in range(int(octaves.max().item()) if octaves.numel() else 0):
        term = amplitude * perlin(p, channels)
        result = torch.where(octaves > i, result + term, result)
        amplitude = amplitude * diminish
        p = p * lacunarity
    return result


def worley(p: torch.Tensor, jitter, style, channels: int) -> torch.Tensor:
    """Worley noise [N, channels] of ``p`` [N,2] or [N,3] with Euclidean distances: the 1..3 smallest
    distances to the jittered feature points of the neighbouring cells (style 0), or cellular noise of
    the nearest feature point's cell (style 1). Ties keep the first cell in the shader's scan order."""
    dims = p.shape[-1]
    n = p.shape[0]
    ints, fracs = zip(*(_floorfrac(p[:, k]) for k in range(dims)))
    local = torch.stack(fracs, -1)
    lattice = torch.stack(ints, -1)
    big = torch.full((n,), 1e6, dtype=p.dtype, device=p.device)
    d = [big] * channels
    minpos = torch.zeros_like(local)
    offsets = [(x, y) for x in (-1, 0, 1) for y in (-1, 0, 1)] if dims == 2 else \
        [(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)]
    for off in offsets:
        o = torch.tensor(off, dtype=torch.int64, device=p.device)
        cell = (lattice + o).to(p.dtype)
        rnd = cell_noise3(cell)[:, :dims]
        pos = ((rnd - 0.5) * jitter + 0.5) + torch.tensor(off, dtype=p.dtype, device=p.device)
        diff = pos - local
        dist = diff[:, 0] * diff[:, 0] + diff[:, 1] * diff[:, 1]
        if dims == 3:
            dist = dist + diff[:, 2] * diff[:, 2]
        first = dist < d[0]
        minpos = torch.where(first[:, None], diff, minpos)
        if channels == 1:
            d = [torch.where(first, dist, d[0])]
        elif channels == 2:
            second = ~first & (dist < d[1])
            d = [torch.where(first, dist, d[0]), torch.where(first, d[0], torch.where(second, dist, d[1]))]
        else:
            second = ~first & (dist < d[1])
            third = ~first & ~second & (dist < d[2])
            d = [torch.where(first, dist, d[0]),
                 torch.where(first, d[0], torch.where(second, dist, d[1])),
                 torch.where(first | second, d[1], torch.where(third, dist, d[2]))]
    distances = torch.stack(d, -1).sqrt()
    q = minpos + p
    solid = cell_noise(q) if channels == 1 else cell_noise3(q)[:, :channels]
    return torch.where(style.reshape(-1, 1) == 1, solid, distances)


# --- node operators ------------------------------------------------------------------------------
def _batch(x: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    return x.expand(like.shape[0], -1) if x.shape[0] == 1 and like.shape[0] != 1 else x


def _noise_channels(p: torch.Tensor, c: int, w_offset: tuple, make) -> torch.Tensor:
    """The shader's channel layout for a C-channel noise: 1 -> the float noise, 2 -> the first two of
    the 3-channel noise, 3 -> it, 4 -> it plus the float noise at ``p + w_offset``."""
    if c == 1:
        return make(p, 1)
    xyz = make(p, 3)
    if c == 2:
        return xyz[:, :2]
    if c == 3:
        return xyz
    shift = torch.tensor([w_offset], dtype=p.dtype, device=p.device)
    return torch.cat([xyz, make(p + shift, 1)], -1)


def _noise_op(coord: str, w_offset: tuple):
    def run(a, n):
        p = a[coord]
        c = CHANNELS[n.type]
        value = _noise_channels(p, c, w_offset, perlin)
        return value * a["amplitude"] + a["pivot"]
    return run


op("noise2d")(_noise_op("texcoord", (19.0, 73.0)))
op("noise3d")(_noise_op("position", (19.0, 73.0, 29.0)))


def _fractal_op(coord: str, w_offset: tuple):
    def run(a, n):
        p = a[coord]
        c = CHANNELS[n.type]

        def make(q, ch):
            return fractal(q, ch, a["octaves"], a["lacunarity"], a["diminish"])

        if c == 2:  # the 2-channel fractal is two float fractals, the second at the offset point
            shift = torch.tensor([w_offset], dtype=p.dtype, device=p.device)
            value = torch.cat([make(p, 1), make(p + shift, 1)], -1)
        else:
            value = _noise_channels(p, c, w_offset, make)
        return value * a["amplitude"]
    return run


op("fractal2d")(_fractal_op("texcoord", (19.0, 193.0)))
op("fractal3d")(_fractal_op("position", (19.0, 193.0, 17.0)))
op("cellnoise2d")(lambda a, n: cell_noise(a["texcoord"]))
op("cellnoise3d")(lambda a, n: cell_noise(a["position"]))


def _worley_op(coord: str):
    def run(a, n):
        p = a[coord]
        return worley(p, _batch(a["jitter"], p), _batch(a["style"], p), CHANNELS[n.type])
    return run


op("worleynoise2d")(_worley_op("texcoord"))
op("worleynoise3d")(_worley_op("position"))
