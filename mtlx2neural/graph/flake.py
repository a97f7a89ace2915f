"""Torch operators for MaterialX's ``flake2d`` and ``flake3d`` (metallic-paint flakes), bit-compatible with
its shader code's hashes.

Behaviour (MaterialX 1.39.5's nodedefs and shader library): space is cut into cubic cells of edge ``size``
(in units of the input space: the texcoord, as (u, v, 0), for flake2d; the position for flake3d).  A cell
holds a flake with a probability that a fitted curve gives for the ``coverage`` density; a flake is a cube
of half-edge 1.5 / sqrt(3) cells about the cell's centre, turned by a random rotation (Arvo's fast random
rotation from three cell hashes), with a random priority.  A point takes the highest-priority flake of the
3 x 3 x 3 cells about it whose cube contains it (a later cell wins a tie).  Outputs:

* ``presence``: that priority in (0, 1), 0 where no flake covers the point;
* ``rand``: a per-flake random number in [0, 1) (0 without a flake); ``id``: ``int(rand * (2^24 - 1))``,
  0 without a flake;
* ``flakenormal``: the flake's normal, drawn from a GGX distribution of width ``roughness^2`` about
  ``normal`` (azimuth measured from ``tangent`` towards ``bitangent``) and normalised; ``normal`` itself,
  unnormalised, without a flake.

The random numbers are MaterialX's cell noises (:mod:`mtlx2neural.graph.noise`: Jenkins' lookup3 hashes
of the integer cell coordinates, with a fourth coordinate 3 for the priority and 2 for the normal's
samples), so the flake pattern matches MaterialX's, not just its statistics.  The frame inputs are a
shading frame (:data:`mtlx2neural.graph.geometry.FRAME_INPUTS`): in the baked material the local one.
"""

from __future__ import annotations

import math

import torch

from mtlx2neural.graph.noise import (
    _bits_to_01,
    _final,
    _mix,
    _seed,
    _u32,
    cell_noise,
    cell_noise3,
)
from mtlx2neural.graph.ops import normalize, op

HALF_EDGE = 1.5 / math.sqrt(3.0)
"""Half the edge of a flake's cube, in cells."""
# The fitted coverage -> probability curve: (A x^2 + B x) / (C x^3 + D x^2 + E x + F).
_FIT = (-26.19771808, 26.39663835, 85.53857017, -102.35069432, -101.42634862, 118.45082288)


def coverage_probability(x: torch.Tensor) -> torch.Tensor:
    """The probability that a cell holds a flake for the coverage density ``x`` in [0, 1]."""
    a, b, c, d, e, f = _FIT
    xx = x * x
    return (a * xx + b * x) / (c * xx * x + d * xx + e * x + f)


def _ints(p: torch.Tensor) -> list[torch.Tensor]:
    return [torch.floor(p[:, k]).to(torch.int64) for k in range(p.shape[-1])]


def cell_noise_w(cell: torch.Tensor, w: float) -> torch.Tensor:
    """The cell noise [N,1] in [0, 1] of the 4D cell (floor(cell), w) (the shader's float cell noise of a
    vec4: one hash of four integers)."""
    x, y, z = _ints(cell)
    s = _seed(4)
    a, b, c = _mix(_u32(s + x), _u32(s + y), _u32(s + z))
    a = _u32(a + math.floor(w))
    return _bits_to_01(_final(a, b, c))[:, None]


def cell_noise3_w(cell: torch.Tensor, w: float) -> torch.Tensor:
    """Three cell noises [N,3] in [0, 1] of the 4D cell (floor(cell), w) (the shader's vec3 cell noise of
    a vec4)."""
    x, y, z = _ints(cell)
    s = _seed(5)
    a, b, c = _mix(_u32(s + x), _u32(s + y), _u32(s + z))
    a = _u32(a + math.floor(w))
    return torch.stack([_bits_to_01(_final(a, _u32(b + k), c)) for k in range(3)], -1)


def rotate_flake(p: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """``p`` [N,3] turned by the random rotation that three uniform numbers ``r`` [N,3] in [0, 1) pick
    (Arvo, "Fast random rotation matrices", Graphics Gems III: a turn by 2 pi r.x about z, then a
    Householder reflection about a direction set by r.y and r.z)."""
    theta = (2.0 * math.pi) * r[:, 0]
    phi = (2.0 * math.pi) * r[:, 1]
    z = r[:, 2] * 2.0
    rad = z.sqrt()
    vx, vy, vz = phi.sin() * rad, phi.cos() * rad, (2.0 - z).sqrt()
    st, ct = theta.sin(), theta.cos()
    sx, sy = vx * ct - vy * st, vx * st + vy * ct
    px, py, pz = p[:, 0], p[:, 1], p[:, 2]
    # Columns of the rotation: (vx sx - ct, vx sy - st, vx vz), (vy sx + st, vy sy - ct, vy vz),
    # (vz sx, vz sy, 1 - z); the result is their sum weighted by p.
    return torch.stack([
        (vx * sx - ct) * px + (vy * sx + st) * py + (vz * sx) * pz,
        (vx * sy - st) * px + (vy * sy - ct) * py + (vz * sy) * pz,
        (vx * vz) * px + (vy * vz) * py + (1.0 - z) * pz,
    ], -1)


def flake(size, roughness, coverage, position, normal, tangent, bitangent) -> dict:
    """The flake outputs at ``position`` [N,3] (see the module docstring): ``{"id", "rand", "presence"}``
    [N,1] and ``"flakenormal"`` [N,3].  ``size``, ``roughness`` and ``coverage`` are [B,1] (B 1 or N);
    ``normal``, ``tangent``, ``bitangent`` [B,3], the frame the flake normal is built in."""
    n = position.shape[0]
    probability = coverage_probability(coverage.clamp(0.0, 1.0))
    p = position / size
    base = torch.floor(p)
    best = torch.zeros(n, 1, dtype=p.dtype, device=p.device)
    best_cell = torch.zeros(n, 3, dtype=p.dtype, device=p.device)
    limit = HALF_EDGE * HALF_EDGE * 3.0
    for i in (-1, 0, 1):
        for j in (-1, 0, 1):
            for k in (-1, 0, 1):
                cell = base + torch.tensor([[float(i), float(j), float(k)]], dtype=p.dtype, device=p.device)
                local = p - cell - 0.5
                near = (local * local).sum(-1, keepdim=True) < limit
                held = cell_noise(cell) <= probability
                priority = cell_noise_w(cell, 3.0)
                turned = rotate_flake(local, cell_noise3(cell))
                inside = (turned.abs() <= HALF_EDGE).all(-1, keepdim=True)
                take = near & held & (priority >= best) & inside
                best = torch.where(take, priority, best)
                best_cell = torch.where(take, cell, best_cell)
    found = best > 0.0
    sample = cell_noise3_w(best_cell, 2.0)
    xi0, xi1, rand = sample[:, :1], sample[:, 1:2], sample[:, 2:3]
    phi = (2.0 * math.pi) * xi0
    tan_t = roughness * roughness * xi1.sqrt() / (1.0 - xi1).clamp_min(1e-30).sqrt()  # GGX
    sin_t = tan_t / (1.0 + tan_t * tan_t).sqrt()
    cos_t = (1.0 - sin_t * sin_t).clamp_min(0.0).sqrt()
    bent = normalize(tangent * (phi.cos() * sin_t) + bitangent * (phi.sin() * sin_t) + normal * cos_t)
    zero = torch.zeros_like(best)
    return {
        "id": torch.where(found, torch.trunc(rand * 16777215.0), zero),
        "rand": torch.where(found, rand, zero),
        "presence": torch.where(found, best, zero),
        "flakenormal": torch.where(found, bent, normal.expand(n, 3)),
    }


def _flake_op(coord: str):
    def run(a, nd):
        pos = a[coord]
        if pos.shape[-1] == 2:  # flake2d: the texcoord as (u, v, 0)
            pos = torch.cat([pos, torch.zeros_like(pos[:, :1])], -1)
        return flake(a["size"], a["roughness"], a["coverage"], pos, a["normal"], a["tangent"], a["bitangent"])
    run.__doc__ = f"{coord}-driven flakes: see :func:`flake`."
    return run


op("flake2d")(_flake_op("texcoord"))
op("flake3d")(_flake_op("position"))
