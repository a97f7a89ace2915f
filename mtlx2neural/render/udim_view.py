"""Rendering and measuring UDIM materials: every uv a render or a measure reads inside a trained tile.

A UDIM material (docs/ARCHITECTURE.md, "UDIM latents") is trained on a list of UDIM tiles, tile
``1001 + tu + 10 * tv`` covering uv in ``[tu, tu+1) x [tv, tv+1)``; its neural model raises
``ValueError`` for a uv in any other tile. The evaluation geometry (:class:`.geometry.Sphere`,
:class:`.geometry.Plane`) spans uv in [0, 1]^2, i.e. tile 1001 only, which a UDIM material may not
even have. Two wrappers make any :class:`~mtlx2neural.contract.Material` read the right tiles; both
only rewrite ``at.uv`` and pass everything else (directions, ``lod``, ``u_level``, ``params``)
through, so the reference, the neural and the analytic material are wrapped alike and common
random numbers still hold:

- :class:`TileView` shows **one tile** on geometry whose uv is not UDIM uv (the sphere's [0, 1]^2,
  the plane's [0, 2]^2): uv is wrapped into the tile, ``frac(uv)`` kept at most ``1 - EDGE`` (a
  rounding error of frac would otherwise land on the next tile), and shifted by the tile's origin
  ``(tu, tv)``; the tile repeats as a plain texture would (a sphere's seam at u = 1 reads u = 0, the
  same column of a periodic map, the tile's left edge here). :func:`compare_tiles` renders the
  analytic views (:func:`.renderer.compare_many`) once per trained tile this way.
- :class:`ClampToTiles` serves geometry whose uv is already the true, multi-tile uv (a stage's
  meshes, :mod:`.in_scene`): each uv goes to the trained tile holding it, or, when it falls outside
  every trained tile (a mesh touching an untrained tile only along an edge, where interpolation
  lands on ``u = 2.0`` exactly), to the nearest trained tile clamped to ``[o, o + 1 - EDGE]``.
  The trained tiles are those the meshes overlap with positive area
  (:func:`mtlx2neural.scene.udim_tiles.touched_tiles`), so only such edge points move; the
  generated Slang shades a point outside the trained tiles black instead.
"""

from __future__ import annotations

import torch

from mtlx2neural.contract import ShadingPoint, as_point
from mtlx2neural.imaging.udim import tile_of_udim
from mtlx2neural.render.renderer import VIEWS, compare_many

EDGE = 1e-5
"""How far inside a tile's upper edges a clamped uv stays (uv units): above float32's spacing at
u = 10 (9.5e-7), so ``floor`` keeps the tile."""


def model_tiles(material) -> list[int] | None:
    """The trained UDIM tiles of a neural material (``material.latents.tile_list``) or an analytic
    baseline (``material.maps.tile_list``); None for any other material (not UDIM, the reference)."""
    for attr in ("latents", "maps"):
        pyramid = getattr(material, attr, None)
        if pyramid is not None and hasattr(pyramid, "tile_list"):
            return pyramid.tile_list
    return None


class _UvRewrite:
    """A material whose every call sees ``at.uv`` rewritten by ``self._uv(uv, rows)``."""

    def __init__(self, material):
        self.material = material

    def _point(self, at, rows: int, uv=None, params=None) -> ShadingPoint:
        """``at`` (or the reference's legacy ``uv=``/``params=`` keywords) with its uv rewritten."""
        p = as_point(at)
        uv = p.uv if uv is None else uv
        return ShadingPoint(self._uv(uv, rows), p.lod, p.u_level, p.params if params is None else params)

    def eval(self, wi, wo, at=None, *, uv=None, params=None):
        return self.material.eval(wi, wo, self._point(at, len(wi), uv, params))

    def sample(self, wi, u, at=None, *, uv=None, params=None):
        return self.material.sample(wi, u, self._point(at, len(wi), uv, params))

    def pdf(self, wi, wo, at=None, *, uv=None, params=None):
        return self.material.pdf(wi, wo, self._point(at, len(wi), uv, params))

    def albedo(self, wi, at=None, samples: int = 256, seed: int = 0):
        return self.material.albedo(wi, self._point(at, len(wi)), samples=samples, seed=seed)

    def environment_lobes(self, wi, at=None):
        return self.material.environment_lobes(wi, self._point(at, len(wi)))

    def describe(self) -> dict:
        return self.material.describe()

    def __getattr__(self, name):  # resolution, latents, dtype, device ... of the wrapped material
        if name == "material":
            raise AttributeError(name)
        return getattr(self.material, name)


class TileView(_UvRewrite):
    """``material`` on geometry with uv in [0, 1]^2 as UDIM tile ``tile`` sees it (module docstring):
    uv -> min(frac(uv), 1 - EDGE) + (tu, tv); no uv (``None``) -> the tile's centre."""

    def __init__(self, material, tile: int):
        super().__init__(material)
        self.tile = int(tile)
        self.origin = tile_of_udim(self.tile)

    def _uv(self, uv, rows: int) -> torch.Tensor:
        if uv is None:
            return torch.tensor([[self.origin[0] + 0.5, self.origin[1] + 0.5]]).expand(rows, 2)
        uv = torch.as_tensor(uv)
        return (uv - torch.floor(uv)).clamp(0.0, 1.0 - EDGE) + uv.new_tensor(self.origin)


class ClampToTiles(_UvRewrite):
    """``material`` read only inside ``tiles`` (UDIM numbers; module docstring): a true uv in a trained
    tile is kept (clamped below its upper edges by EDGE), any other goes to the nearest trained tile,
    clamped to it."""

    def __init__(self, material, tiles):
        super().__init__(material)
        self.tiles = sorted(int(t) for t in tiles)
        if not self.tiles:
            raise ValueError("ClampToTiles needs at least one trained tile")
        self.origins = torch.tensor([tile_of_udim(t) for t in self.tiles], dtype=torch.float64)

    def _uv(self, uv, rows: int) -> torch.Tensor:
        if uv is None:
            return torch.tensor([[float(self.origins[0, 0]) + 0.5, float(self.origins[0, 1]) + 0.5]]).expand(rows, 2)
        uv = torch.as_tensor(uv)
        o = self.origins.to(device=uv.device)
        x = uv.to(torch.float64)
        d = (x[:, None, :] - (o[None] + 0.5)).abs() - 0.5  # [N,T,2] per-axis distance outside each tile
        dist = d.clamp_min(0).square().sum(-1) - (d.max(-1).values < 0).to(x.dtype)  # inside: < 0
        near = o[dist.argmin(1)]
        return torch.minimum(torch.maximum(x, near), near + 1.0 - EDGE).to(uv.dtype)


def compare_tiles(reference, models: dict, texels: tuple[int, int], tiles, views=VIEWS, **kwargs) -> dict:
    """:func:`.renderer.compare_many` of the analytic views once per UDIM tile of ``tiles``: the
    reference and every model of ``models`` wrapped in :class:`TileView` of that tile. Returns
    ``{label: [per-view dict, tile by tile (in ``tiles`` order), view by view]}``, each dict also
    holding ``"tile"`` (its UDIM number). ``kwargs``: compare_many's (res, spp, geometry, lights ...)."""
    out = {label: [] for label in models}
    for tile in tiles:
        per = compare_many(TileView(reference, tile), {k: TileView(m, tile) for k, m in models.items()},
                           texels, views, **kwargs)
        for label, rows in per.items():
            out[label] += [{**r, "tile": int(tile)} for r in rows]
    return out
