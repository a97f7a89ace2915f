"""UDIM / UVTILE texture sets: filename tokens, tile discovery and tile addressing.

Tile numbering (MaterialX and USD agree):

* ``<UDIM>`` is replaced by the four-digit number ``1001 + tu + 10 * tv``, where
  ``tu = floor(u)`` in ``0..9`` and ``tv = floor(v)`` (``tv >= 0``). USD's
  ``UsdUVTexture`` uses the same ``<UDIM>`` token and numbering.
* ``<UVTILE>`` is replaced by ``u<U>_v<V>`` with 1-based ``U = tu + 1`` and
  ``V = tv + 1`` (the Mudbox convention MaterialX adopts), so ``u1_v1`` is tile
  1001 and ``u2_v1`` is tile 1002.

Tiles are discovered on disk by matching the pattern against the files that
exist, so a set may have holes. Tile coordinates are integers ``(tu, tv)``; a
UDIM set spans the bounding box of its tiles ``[tu_min, tu_max + 1] x
[tv_min, tv_max + 1]`` in uv units, which is the range MaterialX's hardware
shader generators map onto ``[0, 1]`` (``getUdimScaleAndOffset`` with
``hwNormalizeUdimTexCoords``) before applying the sampler's address modes.
(MaterialX's generated code computes ``uv * scale + offset`` with
``offset = -min tile``, which is only right when the set starts at u = 0 or is
one tile wide; this module uses the bounding box the function describes.)
OSL / OpenImageIO instead apply the wrap modes inside each tile; both agree for
uv inside the set's tiles.
"""

from __future__ import annotations

import glob
import math
import os
import re
from dataclasses import dataclass

import torch

from mtlx2neural.errors import InputError

UDIM_TOKEN = "<UDIM>"
"""MaterialX and USD token for four-digit UDIM numbers (1001, 1002, ...)."""

UVTILE_TOKEN = "<UVTILE>"
"""MaterialX token for Mudbox-style ``u<U>_v<V>`` tile names (1-based)."""

_MAX_TU = 10  # UDIM numbers encode u tiles 0..9 only


def is_tiled_path(path: str) -> bool:
    """True when ``path`` contains a ``<UDIM>`` or ``<UVTILE>`` token."""
    return UDIM_TOKEN in str(path) or UVTILE_TOKEN in str(path)


def udim_number(tu: int, tv: int) -> int:
    """UDIM number of tile ``(tu, tv)``: ``1001 + tu + 10 * tv``."""
    return 1001 + tu + 10 * tv


def tile_of_udim(udim: int) -> tuple[int, int]:
    """Tile coordinates ``(tu, tv)`` of a UDIM number (inverse of :func:`udim_number`)."""
    if udim < 1001:
        raise ValueError(f"UDIM number {udim} is below 1001.")
    k = udim - 1001
    return k % 10, k // 10


def udim_at(u: float, v: float) -> int | None:
    """UDIM number of the tile holding the point ``(u, v)``, or None where no UDIM tile is (u outside
    ``[0, 10)``, v < 0, or not finite)."""
    if not (math.isfinite(u) and math.isfinite(v) and 0 <= u < _MAX_TU and v >= 0):
        return None
    return udim_number(int(math.floor(u)), int(math.floor(v)))


def udim_of_uv(uv: torch.Tensor) -> torch.Tensor:
    """:func:`udim_at` for a batch: UDIM numbers [N] (int64) of uv [N, 2], -1 where no UDIM tile is."""
    tu, tv = torch.floor(uv[:, 0]), torch.floor(uv[:, 1])
    ok = (tu >= 0) & (tu < _MAX_TU) & (tv >= 0) & torch.isfinite(uv).all(-1)
    return torch.where(ok, 1001 + tu + 10 * tv, torch.full_like(tu, -1)).long()


def check_tiles(tiles) -> list[int]:
    """``tiles`` as a sorted list of UDIM numbers; ValueError unless they are distinct and >= 1001."""
    out = sorted(int(t) for t in tiles)
    if not out or out[0] < 1001 or len(set(out)) != len(out):
        raise ValueError(f"UDIM tiles must be distinct numbers >= 1001, got {out}")
    return out


def tile_path(pattern: str, tu: int, tv: int) -> str:
    """The file name of tile ``(tu, tv)`` for a ``<UDIM>`` / ``<UVTILE>`` pattern."""
    return (str(pattern).replace(UDIM_TOKEN, str(udim_number(tu, tv)))
            .replace(UVTILE_TOKEN, f"u{tu + 1}_v{tv + 1}"))


def _pattern_regex(pattern: str) -> re.Pattern:
    """A regex for the whole path, with one named group per token occurrence."""
    parts = re.split(r"(<UDIM>|<UVTILE>)", pattern)
    out, k = [], 0
    for part in parts:
        if part == UDIM_TOKEN:
            out.append(f"(?P<udim{k}>1[0-9]{{3}})")
            k += 1
        elif part == UVTILE_TOKEN:
            out.append(f"u(?P<U{k}>[0-9]+)_v(?P<V{k}>[0-9]+)")
            k += 1
        else:
            out.append(re.escape(part))
    return re.compile("".join(out))


def _match_tile(rx: re.Pattern, path: str) -> tuple[int, int] | None:
    """Tile coordinates of ``path`` under the pattern, or None if it does not match.

    When a token occurs more than once, every occurrence must name the same tile.
    """
    m = rx.fullmatch(path)
    if m is None:
        return None
    tiles = set()
    for name, val in m.groupdict().items():
        if name.startswith("udim"):
            udim = int(val)
            if udim < 1001:
                return None
            tiles.add(tile_of_udim(udim))
    ks = {name[1:] for name in m.groupdict() if name[0] in "UV"}
    for k in ks:
        u, v = int(m.group(f"U{k}")), int(m.group(f"V{k}"))
        if u < 1 or v < 1 or u > _MAX_TU:
            return None
        tiles.add((u - 1, v - 1))
    return tiles.pop() if len(tiles) == 1 else None


def discover_tiles(pattern: str) -> dict[tuple[int, int], str]:
    """Find the tiles of a ``<UDIM>`` / ``<UVTILE>`` set that exist on disk.

    Returns ``{(tu, tv): file path}`` sorted by UDIM number; empty when no tile
    exists. The tokens may appear anywhere in the path, directories included.
    """
    pattern = os.fspath(pattern)
    rx = _pattern_regex(pattern)
    glob_pat = "".join(
        "[0-9][0-9][0-9][0-9]" if p == UDIM_TOKEN else "u*_v*" if p == UVTILE_TOKEN else glob.escape(p)
        for p in re.split(r"(<UDIM>|<UVTILE>)", pattern))
    found: dict[tuple[int, int], str] = {}
    for path in glob.glob(glob_pat):
        tile = _match_tile(rx, path)
        if tile is not None and os.path.isfile(path):
            found[tile] = path
    return dict(sorted(found.items(), key=lambda kv: udim_number(*kv[0])))


@dataclass(frozen=True)
class UdimRange:
    """The uv rectangle a UDIM set covers: ``[u0, u1] x [v0, v1]`` in uv units (integers).

    It is the bounding box of the set's tiles. MaterialX's hardware shader
    generators treat a UDIM set as one texture over this rectangle: address
    modes (periodic / clamp / mirror / constant) act on its edges, not on each
    tile's edges.
    """

    u0: int
    v0: int
    u1: int
    v1: int

    @classmethod
    def of_tiles(cls, tiles) -> UdimRange:
        """Bounding box of an iterable of ``(tu, tv)`` tiles."""
        tiles = list(tiles)
        if not tiles:
            raise ValueError("a UDIM range needs at least one tile.")
        tus = [t[0] for t in tiles]
        tvs = [t[1] for t in tiles]
        return cls(min(tus), min(tvs), max(tus) + 1, max(tvs) + 1)


def resolve_udim_set(pattern: str, *, udimset=None, node: str | None = None) -> dict[tuple[int, int], str | None]:
    """Tiles of a UDIM set: ``{(tu, tv): path or None}``.

    ``udimset`` optionally declares the set's tiles (UDIM numbers, e.g. from a
    MaterialX document's ``udimset`` geomprop); a declared tile with no file maps
    to None, and files on disk outside the declaration are ignored. Without it,
    the set is what :func:`discover_tiles` finds.

    Raises InputError, naming the pattern and ``node``, when no tile exists.
    """
    found = discover_tiles(pattern)
    if udimset is not None:
        declared = [tile_of_udim(int(u)) for u in udimset]
        tiles = {t: found.get(t) for t in sorted(set(declared), key=lambda t: udim_number(*t))}
    else:
        tiles = dict(found)
    if not any(p is not None for p in tiles.values()):
        where = f" used by node '{node}'" if node else ""
        raise InputError(
            f"no tile of the UDIM texture set '{pattern}'{where} exists on disk "
            f"(looked for {tile_path(pattern, 0, 0)} and the other tiles). Fix the path or provide the files.")
    return tiles
