"""Which UDIM tiles the bound meshes' UVs touch: the tiles a UDIM material's latents are trained on.

A UDIM tile ``1001 + tu + 10 * tv`` covers uv in ``[tu, tu+1) x [tv, tv+1)``
(:mod:`mtlx2neural.imaging.udim`). A mesh touches a tile when one of its UV triangles overlaps
the tile's square with positive area (a triangle that only meets a tile along an edge or at a
corner, as a plane's triangles spanning v in [0, 1] meet tile 1011 along v = 1, does not touch
it). The test is exact for triangles (separating axes: the square's two axes and the
triangle's three edge normals); zero-area UV triangles touch nothing. UVs with u outside
[0, 10) or v < 0 have no UDIM tile: they are reported, not trained.

The meshes are read as :mod:`mtlx2neural.scene.uv_raster` reads them (the ``st`` primvar, else
the first ``texCoord2f[]`` primvar; GeomSubsets: their faces only).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from mtlx2neural.imaging.udim import udim_number
from mtlx2neural.scene.mesh_reading import mesh_triangles

_EPS = 1e-9  # overlap below this (in uv units) is a shared edge, not area


def _overlaps(tri: np.ndarray, tu: np.ndarray, tv: np.ndarray) -> np.ndarray:
    """[T] whether triangle ``tri`` [T,3,2] overlaps the square [tu, tu+1] x [tv, tv+1] ([T] each)
    with positive area (separating-axis test with a strict margin)."""
    lo = np.stack([tu, tv], -1).astype(np.float64)
    hi = lo + 1.0
    ok = np.ones(len(tri), dtype=bool)
    for a in range(2):  # the square's axes
        ok &= (tri[:, :, a].max(1) > lo[:, a] + _EPS) & (tri[:, :, a].min(1) < hi[:, a] - _EPS)
    sq = np.stack([lo, np.stack([hi[:, 0], lo[:, 1]], -1), hi, np.stack([lo[:, 0], hi[:, 1]], -1)], 1)  # [T,4,2]
    for k in range(3):  # the triangle's edge normals
        e = tri[:, (k + 1) % 3] - tri[:, k]
        n = np.stack([-e[:, 1], e[:, 0]], -1)
        norm = np.linalg.norm(n, axis=-1)
        n = n / np.where(norm == 0, 1.0, norm)[:, None]
        pt = (tri * n[:, None, :]).sum(-1)
        ps = (sq * n[:, None, :]).sum(-1)
        ok &= (pt.max(1) > ps.min(1) + _EPS) & (pt.min(1) < ps.max(1) - _EPS)
    return ok


def triangle_tiles(tuv: np.ndarray) -> tuple[list[int], int]:
    """(sorted UDIM numbers that the UV triangles ``tuv`` [T,3,2] overlap with positive area, the
    number of triangles with area outside every UDIM tile: u < 0, u >= 10 or v < 0)."""
    tuv = np.asarray(tuv, dtype=np.float64).reshape(-1, 3, 2)
    d1, d2 = tuv[:, 1] - tuv[:, 0], tuv[:, 2] - tuv[:, 0]
    tuv = tuv[np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) > 0]
    if len(tuv) == 0:
        return [], 0
    lo = np.floor(tuv.min(1) + _EPS).astype(np.int64)
    hi = np.ceil(tuv.max(1) - _EPS).astype(np.int64) - 1  # last tile index whose interior is reached
    hi = np.maximum(hi, lo)
    outside = int(((tuv.min(1)[:, 0] < -_EPS) | (tuv.max(1)[:, 0] > 10 + _EPS) | (tuv.min(1)[:, 1] < -_EPS)).sum())
    found: set[int] = set()
    single = (lo == hi).all(1)
    for tu, tv in {(int(a), int(b)) for a, b in lo[single]}:
        if 0 <= tu < 10 and tv >= 0:
            found.add(udim_number(tu, tv))
    for i in np.nonzero(~single)[0]:  # triangles across tile borders: test each candidate tile
        cand = [(a, b) for a in range(lo[i, 0], hi[i, 0] + 1) for b in range(lo[i, 1], hi[i, 1] + 1)
                if 0 <= a < 10 and b >= 0]
        if not cand:
            continue
        tus, tvs = (np.array(c) for c in zip(*cand))
        hit = _overlaps(np.repeat(tuv[i:i + 1], len(cand), 0), tus, tvs)
        found.update(udim_number(int(a), int(b)) for a, b, h in zip(tus, tvs, hit) if h)
    return sorted(found), outside


def touched_tiles(stage, prim_paths: Iterable[str]) -> tuple[list[int], list[str]]:
    """(sorted UDIM numbers of the tiles the UVs of the meshes / GeomSubsets ``prim_paths`` on
    ``stage`` overlap, notes naming prims left out or UVs outside every tile)."""

    tiles: set[int] = set()
    notes = []
    for path in prim_paths:
        found = mesh_triangles(stage, path, ())
        if isinstance(found, str):
            notes.append(f"{path}: {found}: its UDIM tiles are not known")
            continue
        got, outside = triangle_tiles(found[0])
        tiles.update(got)
        if outside:
            notes.append(f"{path}: {outside} UV triangles reach outside the UDIM range (u in [0, 10), v >= 0); "
                         f"that part is not trained")
    return sorted(tiles), notes
