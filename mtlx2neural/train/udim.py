"""UDIM materials in training: one parameter stack per trained tile, uv drawn over the tiles.

A material whose graph reads a UDIM texture set (an image ``file`` with ``<UDIM>`` or
``<UVTILE>``; :func:`udim_patterns`) is trained on a list of UDIM tiles: those the bound meshes'
UVs touch (:func:`mtlx2neural.scene.udim_tiles.touched_tiles`), or, for ``.mtlx`` input without
meshes, every tile present on disk (:func:`tiles_on_disk`). Tile ``1001 + tu + 10 * tv`` covers
uv in ``[tu, tu+1) x [tv, tv+1)``; its latent pyramid (:mod:`mtlx2neural.model.latent`) is
addressed by ``frac(uv)``.

:class:`TiledStack` holds one :class:`~mtlx2neural.textures.parameter_stack.ParameterStack` per
tile, each built by evaluating the material graph at the tile's *true* uv (``tile origin +
texel centre``), so the textures' own UDIM mapping picks the tile's files. It answers the
stack's lookups (``sample``, ``sample_raw``) at true uv: each point reads the trained tile that
contains it, or, for the footprint points that stray outside every trained tile, the nearest
trained tile clamped to its edge. The trainer draws uv uniformly over the trained tiles
(:func:`draw_uv`: a uniform tile, then a uniform point in it; every tile has area 1, so this is
area-proportional) and evaluates the reference at that true uv.

Limits: every tile shares one latent grid (the largest tile image's, times the image's UV scale:
:func:`tile_resolution`), and geometry-driven inputs (``position``, primvars) are rasterised over
[0, 1]^2 only, so they are not supported with UDIM yet.
"""

from __future__ import annotations

import dataclasses

import torch

from mtlx2neural.graph.ir import Const
from mtlx2neural.imaging.udim import (
    discover_tiles,
    is_tiled_path,
    tile_of_udim,
    udim_number,
)
from mtlx2neural.scene.udim_tiles import touched_tiles
from mtlx2neural.textures.parameter_stack import (
    ParameterStack,
    build_parameter_stack,
    texture_resolution,
)


def udim_patterns(compiled) -> list[tuple[str, str]]:
    """(image node path, file pattern) of every image node whose ``file`` is a UDIM / UVTILE set."""
    out = []
    for i in compiled.spatial_nodes:
        n = compiled.graph[i]
        f = n.inputs.get("file")
        if n.category in ("image", "tiledimage") and isinstance(f, Const) and f.value and is_tiled_path(f.value):
            out.append((n.path, str(f.value)))
    return out


def tiles_on_disk(compiled) -> list[int]:
    """Sorted UDIM numbers of every tile file of the material's UDIM sets (the tiles trained for
    ``.mtlx`` input without meshes)."""
    return sorted({udim_number(*t) for _, pat in udim_patterns(compiled) for t in discover_tiles(pat)})


def tile_resolution(compiled) -> tuple[int, int]:
    """(H, W) latent grid per tile: :func:`texture_resolution`, which counts a UDIM set by its largest
    tile (one tile spans one uv unit, as a plain image spans [0,1]^2)."""
    h, w, _ = texture_resolution(compiled)
    return h, w


class _OffsetEvaluator:
    """The material's evaluator with every ``run``'s uv shifted by a tile's origin."""

    def __init__(self, ev, offset: tuple[float, float]):
        self._ev, self._offset = ev, offset

    def run(self, nodes, uv, *args, **kwargs):
        return self._ev.run(nodes, uv + uv.new_tensor(self._offset), *args, **kwargs)

    def __getattr__(self, name):
        return getattr(self._ev, name)


@dataclasses.dataclass
class TiledStack:
    """One parameter stack per trained UDIM tile (``tiles``, sorted UDIM numbers; ``stacks`` in the
    same order, all of one resolution). Lookups take true uv (module docstring)."""

    tiles: list[int]
    stacks: list[ParameterStack]

    @property
    def levels(self) -> list[torch.Tensor]:
        """The first tile's levels: the channel count and level sizes every tile shares."""
        return self.stacks[0].levels

    def __getattr__(self, name):  # channels, constants, notes, texel_ratio, resolution, offsets ...
        if name in ("stacks", "tiles"):
            raise AttributeError(name)
        return getattr(self.stacks[0], name)

    def origins(self, device=None) -> torch.Tensor:
        """[T, 2] uv of each tile's lower-left corner (tu, tv)."""
        return torch.tensor([tile_of_udim(t) for t in self.tiles], dtype=torch.float32, device=device)

    def locate(self, uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(tile index [N] into ``tiles``, local uv [N,2] in [0, 1]) of true uv [N,2]: the trained tile
        holding each point, else the nearest trained tile (distance to its square) clamped to its edge."""
        o = self.origins(uv.device).to(uv.dtype)
        d = (uv[:, None, :] - (o[None] + 0.5)).abs() - 0.5  # [N,T,2] per-axis distance outside each tile
        dist = d.clamp_min(0).square().sum(-1) - (d.max(-1).values < 0).to(uv.dtype)  # inside: < 0
        idx = dist.argmin(1)
        return idx, (uv - o[idx]).clamp(0.0, 1.0)

    def sample(self, uv: torch.Tensor, level: int = 0) -> dict:
        """Every varying parameter at true uv [N,2] in MIP ``level`` (as ParameterStack.sample)."""
        idx, local = self.locate(uv)
        parts = [(torch.nonzero(idx == t)[:, 0], self.stacks[t].sample(local[idx == t], level))
                 for t in torch.unique(idx).tolist()]
        out = {}
        for rows, vals in parts:
            for k, v in vals.items():
                if k not in out:
                    out[k] = v.new_zeros(uv.shape[0], v.shape[1])
                out[k][rows] = v
        return out

    def sample_raw(self, uv: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
        """Undecoded channels [N, C] at true uv with per-query integer ``level`` [N] (the encoder's input)."""
        idx, local = self.locate(uv)
        out = torch.zeros(uv.shape[0], self.levels[0].shape[0], dtype=torch.float32, device=uv.device)
        for t in torch.unique(idx).tolist():
            rows = torch.nonzero(idx == t)[:, 0]
            out[rows] = self.stacks[t].sample_raw(local[rows], level[rows])
        return out


def build_tiled_stack(compiled, tiles, resolution: tuple[int, int] | None = None, **kwargs) -> TiledStack:
    """A :class:`TiledStack` over ``tiles`` (UDIM numbers): one
    :func:`~mtlx2neural.textures.parameter_stack.build_parameter_stack` per tile at ``resolution``
    (default :func:`tile_resolution`), the graph evaluated at the tile's true uv."""
    tiles = sorted(int(t) for t in tiles)
    if not tiles:
        raise ValueError("a UDIM material needs at least one tile to train")
    resolution = tuple(resolution or tile_resolution(compiled))
    stacks = []
    for t in tiles:
        tu, tv = tile_of_udim(t)
        shifted = dataclasses.replace(compiled, evaluator=_OffsetEvaluator(compiled.evaluator, (float(tu), float(tv))))
        stacks.append(build_parameter_stack(shifted, resolution=resolution, **kwargs))
    return TiledStack(tiles, stacks)


def training_tiles(compiled, stage_file: str | None = None, prims=()) -> tuple[list[int] | None, list[str]]:
    """(UDIM tiles to train, notes) for ``compiled``: None when its graph reads no UDIM set; the tiles
    that the meshes ``prims`` of the USD stage ``stage_file`` overlap
    (:func:`~mtlx2neural.scene.udim_tiles.touched_tiles`); every tile on disk (:func:`tiles_on_disk`)
    for ``.mtlx`` input without meshes, or when the meshes give no tile (no UVs), with a note."""
    if not udim_patterns(compiled):
        return None, []
    notes: list[str] = []
    if stage_file and list(prims):
        # Local: opening a stage pulls in pxr's file format plugins; .mtlx input never needs them.
        from mtlx2neural.scene.usd_stage import open_stage

        tiles, notes = touched_tiles(open_stage(str(stage_file)), list(prims))
        if tiles:
            return tiles, notes
        notes.append("the bound meshes touch no UDIM tile: every tile on disk is trained")
    return tiles_on_disk(compiled), notes


def build_training_stack(compiled, stage_file: str | None = None, prims=(), resolution=None):
    """The stack the trainer takes: a :class:`TiledStack` over :func:`training_tiles` for a UDIM
    material, else :func:`~mtlx2neural.textures.parameter_stack.build_parameter_stack` at
    ``resolution``. Returns (stack, notes)."""
    tiles, notes = training_tiles(compiled, stage_file, prims)
    if tiles is None:
        return build_parameter_stack(compiled, resolution=resolution), notes
    return build_tiled_stack(compiled, tiles, resolution), notes + [f"UDIM tiles trained: {tiles}"]


def draw_uv(n: int, tiles: list[int] | None, generator: torch.Generator) -> torch.Tensor:
    """[n, 2] training uv: uniform in [0,1]^2 without ``tiles``; else a uniform tile of ``tiles``
    (UDIM numbers), then a uniform point in it (true uv)."""
    uv = torch.rand(n, 2, generator=generator)
    if not tiles:
        return uv
    pick = torch.randint(len(tiles), (n,), generator=generator)
    origins = torch.tensor([tile_of_udim(t) for t in tiles], dtype=uv.dtype)
    return uv + origins[pick]


def is_udim_stack(stack) -> bool:
    """Whether ``stack`` is a :class:`TiledStack`."""
    return isinstance(stack, TiledStack)


