"""What a conversion will train, decided before any training (shared by ``convert`` and ``inspect``).

For each selected material, :func:`plan_materials` compiles the graph (on the CPU;
it also surfaces bad input before any worker starts) and decides:

- **the latent grid** (:func:`grid_decision`), in texels per UV unit: ``uniform``
  (nothing varies: one 1x1 code), ``native`` (the finest texture's texel grid, UV
  tiling included), ``density`` (``--texel-density D``, latent texels per metre of
  surface: the scene's meshes span ``m`` metres per UV unit
  (:mod:`mtlx2neural.scene.texel_density`, the most demanding bound mesh), so
  ceil(D x m) texels per UV unit suffice; a native grid with a longer side above that
  is scaled down to it, never up) or ``capped`` (scaled down so its longer side is
  ``cfg.max_resolution``, ``--max-texels``, which applies after the density: the
  smaller decides). A grid below the textures' prefilters their finer detail into
  level 0, and the plan carries a warning saying so; a density that has no effect
  (plain ``.mtlx`` input, no bound mesh with UVs, or a grid at least native) is a note;
- **the settings it trains with** (``cfg``): the given ones, except that a grid the
  density decided sets ``max_resolution`` to it, so that the grid follows from the
  settings (:func:`latent_resolution`) and the hashes change with it;
- **the cache key** (``digest``): :func:`mtlx2neural.pipeline.source_hash.source_hash` of the
  material and those settings; with an error budget the decoder is left out of the
  settings and the budget is hashed instead (:func:`cache_key`);
- **the content hash** (:func:`mtlx2neural.pipeline.source_hash.content_hash`, the grid
  included), name-free: materials with equal content hashes would train to the same
  model, so only the first (in scene order) is trained and the others get
  ``shared_with`` = its name. Two equal materials whose meshes imply different grids
  train apart.

Constant parameters never reach the encoder: the parameter stack
(:mod:`mtlx2neural.textures.parameter_stack`) holds only the parameters that vary
over UV, so the encoder's input width is the sum of their channel counts.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import re
from dataclasses import dataclass, field

from mtlx2neural.errors import InputError
from mtlx2neural.graph import compile_material
from mtlx2neural.graph.compile import application_note
from mtlx2neural.graph.geometry import bind_geometry
from mtlx2neural.graph.ops import Application
from mtlx2neural.pipeline.source_hash import content_hash, source_hash
from mtlx2neural.scene.texel_density import (
    open_stage_for,
    surface_density,
    texels_per_uv,
)
from mtlx2neural.textures.parameter_stack import texture_resolution
from mtlx2neural.train.config import TrainConfig
from mtlx2neural.train.udim import training_tiles
from mtlx2neural.universal.choice import STEPS, EncoderChoice, choose_encoder
from mtlx2neural.universal.weights import load_weights, universal_config

DECODERS = ("2x16", "2x32", "3x64")
"""Decoder sizes an error budget escalates through, smallest first."""


def latent_resolution(compiled, cfg: TrainConfig) -> tuple[int, int]:
    """The latent grid (H, W) for ``compiled``: (1, 1) for a uniform material, else the textures'
    texel grid scaled down to ``cfg.max_resolution`` texels per side."""
    return grid_decision(compiled, cfg)[0]


def scaled_grid(h: int, w: int, side: int) -> tuple[int, int]:
    """(H, W) scaled so that the longer side is ``side`` (integer arithmetic: exactly ``side``)."""
    m = max(h, w)
    return max(1, h * side // m), max(1, w * side // m)


def grid_decision(compiled, cfg: TrainConfig, density_texels: int | None = None
                  ) -> tuple[tuple[int, int], tuple[int, int] | None, str]:
    """(latent grid (H, W), native texture grid (H, W) or None when uniform, kind).

    ``density_texels``: texels per UV unit the scene's texel density needs (None: no
    density). ``kind`` is ``uniform``, ``native``, ``density`` (the density is below the
    native grid's longer side and not above the cap) or ``capped`` (the cap is below
    both).
    """
    if not compiled.varying_parameters():
        return (1, 1), None, "uniform"
    h, w, _ = texture_resolution(compiled)
    side, kind = max(h, w), "native"
    if density_texels and density_texels < side:
        side, kind = density_texels, "density"
    if cfg.max_resolution and cfg.max_resolution < side:
        side, kind = cfg.max_resolution, "capped"
    return (scaled_grid(h, w, side) if kind != "native" else (h, w)), (h, w), kind


def cache_key(source, cfg: TrainConfig, allow_missing_textures: bool, max_error: float | None) -> str:
    """The source hash stored in ``summary.json``: with a budget, the decoder is chosen by the run,
    so the budget (and the sizes tried) is hashed instead of ``cfg.decoder``."""
    if max_error is None:
        return source_hash(source, cfg, allow_missing_textures)
    base = source_hash(source, dataclasses.replace(cfg, decoder="budget"), allow_missing_textures)
    return hashlib.sha256(f"{base}\0{budget_tag(max_error)}".encode()).hexdigest()


def application_tag(compiled) -> str:
    """What the hashes add for a graph that reads ``time``/``frame``: the instant it is baked at."""
    if not compiled.reads_application:
        return ""
    app = compiled.application
    return f"\0application=frame {app.frame!r} at {app.fps!r} fps"


def geometry_tag(compiled) -> str:
    """What the hashes add for a graph that reads geometry (:func:`~mtlx2neural.graph.geometry.bind_geometry`):
    the stage file, the bound prims it is rasterised from (or the sphere default) and the digest of their
    mesh data (:meth:`~mtlx2neural.scene.uv_raster.GeometrySource.digest`: points, topology, UVs, normals,
    the primvars read, transforms), so editing a bound mesh retrains; "" when it reads none, so editing a
    mesh never retrains a material that reads no geometry."""
    geo = compiled.evaluator.geometry
    return "" if geo is None else f"\0geometry={geo.stage_file or ''}|{geo.describe()}|{geo.digest()}"


def udim_tag(compiled, source) -> str:
    """What the hashes add for a UDIM material: the tiles it trains (:func:`~mtlx2neural.train.udim.training_tiles`:
    the bound meshes' tiles), so moving a mesh's UVs onto another tile retrains, and two materials with
    one graph on meshes over different tiles do not share a training; "" for any other material."""
    tiles, _ = training_tiles(compiled, getattr(source, "stage_file", None), source.bound_prims)
    return "" if tiles is None else f"\0udim_tiles={','.join(map(str, tiles))}"


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
    """Name-free content hash (the grid included); equal hashes train once."""
    grid: tuple[int, int]
    """Latent grid (H, W) at level 0, texels per UV unit."""
    texture_grid: tuple[int, int] | None
    """The textures' native texel grid (H, W); None for a uniform material."""
    grid_kind: str
    """``uniform``, ``native``, ``density`` or ``capped``."""
    shared_with: str | None = None
    """Name of the earlier material with the same content hash, whose result this one reuses."""
    warnings: list[str] = field(default_factory=list)
    """Decisions that lose something (a grid below the textures'), for the summary's notes and the CLI."""
    cfg: TrainConfig | None = None
    """The settings it trains with (the given ones; ``max_resolution`` = the grid when the density decided)."""
    max_texels: int | None = None
    """The cap asked for (``--max-texels``; the given settings' ``max_resolution``)."""
    texel_density: float | None = None
    """``--texel-density``: latent texels per metre of surface (None: not asked)."""
    surface: object = None
    """The :class:`~mtlx2neural.scene.texel_density.SurfaceDensity` of its bound meshes (None: not measured)."""
    density_texels: int | None = None
    """Texels per UV unit the density needs: ceil(texel_density x metres per UV unit); None: no measure."""
    notes: list[str] = field(default_factory=list)
    """Decisions worth knowing that lose nothing (a density with no effect, and why)."""
    encoder: EncoderChoice = field(default_factory=lambda: EncoderChoice("material"))
    """Its own network, or its shading model's universal one (``--encoder``; :mod:`mtlx2neural.universal.choice`)."""

    @property
    def name(self) -> str:
        return self.source.name

    @property
    def metres_per_uv(self) -> float | None:
        """Metres of surface per UV unit of the most demanding bound mesh (None: not measured)."""
        return self.surface.metres_per_uv if self.surface is not None else None

    def density_text(self) -> str:
        """``D texels/m x m m per UV unit = N texels per UV unit``."""
        return (f"{self.texel_density:g} texels/m x {self.metres_per_uv:.4g} m per UV unit = "
                f"{self.density_texels} texels per UV unit")

    def grid_text(self) -> str:
        """One line for ``inspect`` and the CLI: the grid and why."""
        h, w = self.grid
        if self.grid_kind == "uniform":
            return "1x1 (spatially uniform: a single latent code)"
        th, tw = self.texture_grid
        if self.grid_kind == "density":
            return (f"{w}x{h}, from the scene's texel density ({self.texel_density:g} texels/m; textures "
                    f"{tw}x{th}: finer detail is prefiltered)")
        if self.grid_kind == "capped":
            why = ""
            if self.density_texels is not None:
                why = f"; the texel density implies {self.density_texels}: --max-texels is smaller and decides"
            return f"{w}x{h}, capped (textures {tw}x{th}: finer detail is prefiltered{why})"
        if self.density_texels is not None:
            return (f"{w}x{h} (the textures' native grid; the texel density implies {self.density_texels} "
                    f"per side: never upsampled)")
        return f"{w}x{h} (the textures' native grid)"

    def latent_info(self) -> dict:
        """JSON-friendly grid decision, for ``inspect --json`` and ``summary.json``'s ``latent``."""
        surface = self.surface
        return {"grid": list(self.grid), "kind": self.grid_kind, "max_texels": self.max_texels,
                "texture_grid": list(self.texture_grid) if self.texture_grid else None,
                "text": self.grid_text(), "texel_density": self.texel_density,
                "metres_per_uv": self.metres_per_uv, "density_texels": self.density_texels,
                "meters_per_unit": None if surface is None else surface.meters_per_unit,
                "meters_per_unit_authored": None if surface is None else surface.unit_authored,
                "density_meshes": None if surface is None else [
                    {"prim": m.prim, "metres_per_uv": m.metres_per_uv, "world_area_m2": m.world_area_m2,
                     "uv_area": m.uv_area} for m in surface.meshes],
                "density_skipped": None if surface is None else [
                    {"prim": p, "reason": r} for p, r in surface.skipped],
                "notes": list(self.notes)}


@dataclass
class MaterialFailure:
    """A material left out of a conversion because it cannot be compiled (the others convert)."""

    material: str
    """Its name (USD prim path, or the surfacematerial name for ``.mtlx`` input)."""
    node: str | None
    """The node (or prim) at fault, when the error names one."""
    reason: str
    """The error's message (names the file, node and what to do)."""

    @classmethod
    def of(cls, material: str, exc: InputError) -> MaterialFailure:
        return cls(material, getattr(exc, "node", None) or _named_node(str(exc)), str(exc))

    def record(self) -> dict:
        """JSON-friendly: ``{"material", "node", "reason"}``."""
        return dataclasses.asdict(self)


def _named_node(message: str) -> str | None:
    """The first ``node 'X'`` a message names (errors raised without ``node=``)."""
    found = re.search(r"node '([^']+)'", message)
    return found.group(1) if found else None


def plan_materials(sources, cfg: TrainConfig, allow_missing_textures: bool = False,
                   max_error: float | None = None, texel_density: float | None = None,
                   asset=None, failures: list[MaterialFailure] | None = None,
                   strict: bool = False, application: Application | None = None, encoder: str = "material",
                   universal_steps: int = STEPS, universal_tune: str = "networks") -> list[MaterialPlan]:
    """Compile each of ``sources`` and decide its grid, settings, cache key and sharing (module docstring).

    ``texel_density``: latent texels per metre of surface (``--texel-density``); the
    meshes are measured on the USD stage ``asset`` (a path; the one the sources were
    loaded from). Without a USD ``asset`` it has no effect, and each plan notes why.

    ``failures``: when a list, a material that cannot be compiled (an :class:`InputError`:
    unsupported node, bad value, missing texture) is appended to it as a
    :class:`MaterialFailure` and left out of the plans; None: the error propagates.
    ``strict``: a texture found only by ignoring case is an error instead of a warning
    (:func:`mtlx2neural.graph.compile.compile_material`).
    ``application``: the instant ``time``/``frame`` nodes fold to (None: frame 1 at 24 fps); a
    material that reads them gets a note, and the instant joins its hashes.
    ``encoder`` / ``universal_steps`` / ``universal_tune``: ``--encoder``, ``--universal-steps`` and
    ``--universal-tune``; a material on the universal path has its choice (weights, steps, tune) in its hashes.
    """
    plans, first = [], {}
    stage, no_stage = _density_stage(texel_density, asset)
    for src in sources:
        if getattr(src, "measured", False):  # a MERL table: uniform, nothing to compile
            plans.append(_measured_plan(src, cfg, allow_missing_textures, max_error, first))
            continue
        try:
            compiled = compile_material(src.document, src.material, allow_missing_textures=allow_missing_textures,
                                        strict_case=strict, application=application)
            # A texture reading another UV set than the meshes' layout fails here (graph.geometry.check_uv_sets).
            bind_geometry(compiled, getattr(src, "stage_file", None), src.bound_prims)
        except InputError as exc:
            if failures is None:
                raise
            failures.append(MaterialFailure.of(src.name, exc))
            continue
        surface = implied = None
        notes = []
        tags = geometry_tag(compiled) + application_tag(compiled) + udim_tag(compiled, src)
        if compiled.reads_application:
            notes.append(application_note(src.name, compiled.reads_application, compiled.application))
        if texel_density and compiled.varying_parameters():
            if stage is None:
                notes.append(f"--texel-density has no effect: {no_stage}")
            else:

                surface = surface_density(stage, src.bound_prims)
                if surface.metres_per_uv is None:
                    notes.append(f"--texel-density has no effect: {surface.reason()}")
                else:
                    implied = texels_per_uv(texel_density, surface.metres_per_uv)
        grid, native, kind = grid_decision(compiled, cfg, implied)
        eff = dataclasses.replace(cfg, max_resolution=implied) if kind == "density" else cfg
        choice = choose_encoder(encoder, src.document, src.material, compiled, eff, universal_steps, universal_tune)
        if choice.universal:  # the shipped encoder reads what it was trained on
            eff = universal_config(eff, load_weights(choice.model))
        tags += choice.tag
        content = content_hash(compiled, eff, allow_missing_textures,
                               f"{budget_tag(max_error)}\0grid={grid[0]}x{grid[1]}{tags}")
        key = cache_key(src, eff, allow_missing_textures, max_error)
        if tags:
            key = hashlib.sha256(f"{key}{tags}".encode()).hexdigest()
        plan = MaterialPlan(src, compiled, key, content,
                            grid, native, kind, shared_with=first.get(content), cfg=eff,
                            max_texels=cfg.max_resolution, texel_density=texel_density, surface=surface,
                            density_texels=implied, notes=notes, encoder=choice)
        plan.warnings += list(compiled.case_fixes)
        plan.warnings += [f"{src.name}: {r}" for r in compiled.surface.refused]  # emission left out, said aloud
        _explain(plan, cfg)
        first.setdefault(content, src.name)
        plans.append(plan)
    return plans


def _measured_plan(src, cfg: TrainConfig, allow_missing_textures: bool, max_error: float | None,
                   first: dict) -> MaterialPlan:
    """The plan of a measured BRDF (``MaterialSource.measured``): a 1x1 grid, hashed by the table's bytes."""
    content = content_hash(None, cfg, allow_missing_textures, f"{budget_tag(max_error)}\0grid=1x1",
                           measured=src.source_file)
    plan = MaterialPlan(src, None, cache_key(src, cfg, allow_missing_textures, max_error), content, (1, 1), None,
                        "uniform", shared_with=first.get(content), cfg=cfg, max_texels=cfg.max_resolution,
                        notes=["a measured BRDF (MERL table): isotropic and uniform, one latent code"])
    first.setdefault(content, src.name)
    return plan


def _density_stage(texel_density, asset):
    """(USD stage to measure, None) or (None, why the density cannot apply)."""
    if not texel_density:
        return None, None
    if asset is None:
        return None, "no scene was given to measure"

    stage = open_stage_for(asset)
    return (stage, None) if stage is not None else (
        None, "the input is a MaterialX file, with no geometry to measure (give the USD scene)")


def _explain(plan: MaterialPlan, cfg: TrainConfig) -> None:
    """The plan's warnings and notes about its grid."""
    grid, native, kind = plan.grid, plan.texture_grid, plan.grid_kind
    if kind == "density":
        keep = math.ceil(max(native) / plan.metres_per_uv)
        plan.warnings.append(
            f"{plan.name}: latent grid {grid[1]}x{grid[0]} from the scene's texel density ({plan.density_text()}) "
            f"is below the textures' {native[1]}x{native[0]}: finer detail is prefiltered away; raise "
            f"--texel-density (at least {keep} keeps the textures' grid) or omit it")
    elif kind == "capped":
        plan.warnings.append(
            f"latent grid capped to {grid[1]}x{grid[0]} texels (max {cfg.max_resolution} per side) below the "
            f"textures' {native[1]}x{native[0]}: finer detail is prefiltered away; raise --max-texels "
            f"(0: native) to keep it")
        if plan.density_texels is not None:
            plan.notes.append(f"the scene's texel density ({plan.density_text()}) is above "
                              f"--max-texels {cfg.max_resolution}: the cap decides")
    elif kind == "native" and plan.density_texels is not None:
        plan.notes.append(f"the scene's texel density ({plan.density_text()}) is at least the textures' "
                          f"{native[1]}x{native[0]}: their native grid is kept (never upsampled)")
