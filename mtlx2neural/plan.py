"""What a conversion will train, decided before any training (shared by ``convert`` and ``inspect``).

For each selected material, :func:`plan_materials` compiles the graph (on the CPU;
it also surfaces bad input before any worker starts) and decides:

- **the latent grid** (:func:`latent_resolution`): ``uniform`` (nothing varies: one
  1x1 code), ``native`` (the finest texture's texel grid, UV tiling included) or
  ``capped`` (the native grid scaled down so its longer side is ``cfg.max_resolution``,
  ``--max-texels``; level 0 then prefilters the finer detail, and the plan carries a
  warning saying so);
- **the cache key** (``digest``): :func:`mtlx2neural.export.cache.source_hash` of the
  material and settings; with an error budget the decoder is left out of the settings
  and the budget is hashed instead (:func:`cache_key`);
- **the content hash** (:func:`mtlx2neural.export.cache.content_hash`), name-free:
  materials with equal content hashes would train to the same model, so only the
  first (in scene order) is trained and the others get ``shared_with`` = its name.

Constant parameters never reach the encoder: the parameter stack
(:mod:`mtlx2neural.textures.parameter_stack`) holds only the parameters that vary
over UV, so the encoder's input width is the sum of their channel counts.
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass, field

from .export.cache import content_hash, source_hash
from .graph import compile_material
from .textures.parameter_stack import texture_resolution
from .train.config import TrainConfig

DECODERS = ("2x16", "2x32", "3x64")
"""Decoder sizes an error budget escalates through, smallest first."""


def latent_resolution(compiled, cfg: TrainConfig) -> tuple[int, int]:
    """The latent grid (H, W) for ``compiled``: (1, 1) for a uniform material, else the textures'
    texel grid scaled down to ``cfg.max_resolution`` texels per side."""
    return grid_decision(compiled, cfg)[0]


def grid_decision(compiled, cfg: TrainConfig) -> tuple[tuple[int, int], tuple[int, int] | None, str]:
    """(latent grid (H, W), native texture grid (H, W) or None when uniform, kind).

    ``kind`` is ``uniform``, ``native`` or ``capped`` (native grid larger than the cap).
    """
    if not compiled.varying_parameters():
        return (1, 1), None, "uniform"
    h, w, _ = texture_resolution(compiled)
    if cfg.max_resolution and max(h, w) > cfg.max_resolution:
        s = cfg.max_resolution / max(h, w)
        return (max(1, int(h * s)), max(1, int(w * s))), (h, w), "capped"
    return (h, w), (h, w), "native"


def cache_key(source, cfg: TrainConfig, allow_missing_textures: bool, max_error: float | None) -> str:
    """The source hash stored in ``summary.json``: with a budget, the decoder is chosen by the run,
    so the budget (and the sizes tried) is hashed instead of ``cfg.decoder``."""
    if max_error is None:
        return source_hash(source, cfg, allow_missing_textures)
    base = source_hash(source, dataclasses.replace(cfg, decoder="budget"), allow_missing_textures)
    return hashlib.sha256(f"{base}\0{budget_tag(max_error)}".encode()).hexdigest()


def budget_tag(max_error: float | None) -> str:
    return "" if max_error is None else f"max_error={float(max_error)!r};decoders={','.join(DECODERS)}"


@dataclass
class MaterialPlan:
    """The decisions for one material, before training."""

    source: object
    """The :class:`mtlx2neural.scene.MaterialSource`."""
    compiled: object
    """Its :class:`mtlx2neural.graph.compile.CompiledMaterial` (CPU), for ``inspect``."""
    digest: str
    """Cache key (:func:`cache_key`), stored in ``summary.json`` as ``source_hash``."""
    content: str
    """Name-free content hash; equal hashes train once."""
    grid: tuple[int, int]
    """Latent grid (H, W) at level 0."""
    texture_grid: tuple[int, int] | None
    """The textures' native texel grid (H, W); None for a uniform material."""
    grid_kind: str
    """``uniform``, ``native`` or ``capped``."""
    shared_with: str | None = None
    """Name of the earlier material with the same content hash, whose result this one reuses."""
    warnings: list[str] = field(default_factory=list)
    """Decisions that lose something (a capped grid), for the summary's notes and the CLI."""

    @property
    def name(self) -> str:
        return self.source.name

    def grid_text(self) -> str:
        """One line for ``inspect`` and the CLI: the grid and why."""
        h, w = self.grid
        if self.grid_kind == "uniform":
            return "1x1 (spatially uniform: a single latent code)"
        th, tw = self.texture_grid
        if self.grid_kind == "capped":
            return f"{w}x{h}, capped (textures {tw}x{th}: finer detail is prefiltered)"
        return f"{w}x{h} (the textures' native grid)"


def plan_materials(sources, cfg: TrainConfig, allow_missing_textures: bool = False,
                   max_error: float | None = None) -> list[MaterialPlan]:
    """Compile each of ``sources`` and decide its grid, cache key and sharing (module docstring)."""
    plans, first = [], {}
    for src in sources:
        compiled = compile_material(src.document, src.material, allow_missing_textures=allow_missing_textures)
        grid, native, kind = grid_decision(compiled, cfg)
        content = content_hash(compiled, cfg, allow_missing_textures, budget_tag(max_error))
        plan = MaterialPlan(src, compiled, cache_key(src, cfg, allow_missing_textures, max_error), content,
                            grid, native, kind, shared_with=first.get(content))
        if kind == "capped":
            plan.warnings.append(
                f"latent grid capped to {grid[1]}x{grid[0]} texels (max {cfg.max_resolution} per side) below the "
                f"textures' {native[1]}x{native[0]}: finer detail is prefiltered away; raise --max-texels "
                f"(0: native) to keep it")
        first.setdefault(content, src.name)
        plans.append(plan)
    return plans
