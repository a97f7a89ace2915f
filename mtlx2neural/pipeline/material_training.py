"""Training one material: the neural model, its measures and the UsdPreviewSurface fallback's fit.

:func:`train_material` compiles the material's graph, builds its training stack, trains the neural
decoder (:class:`~mtlx2neural.train.trainer.Trainer`), fits the analytic baseline of the layer's
UsdPreviewSurface fallback (:func:`fit_preview`), measures both against the reference BRDF and
writes the material's folder: ``checkpoint.pt``, ``training_curves.csv``, PNGs of every view,
``analytic_baseline.pt`` and the :class:`~mtlx2neural.material_record.MaterialRecord`
(``summary.json``).

Fidelity is measured twice for a USD source whose material is bound to meshes: on the analytic
views (``flip_mean``: the unit sphere, three directional views and one under the sky,
:mod:`~mtlx2neural.render.summary_views`)
and in the scene (``flip_in_scene``, :mod:`.in_scene_measure`).

A UDIM material (its graph reads a ``<UDIM>`` texture set) trains only its tiles
(:func:`mtlx2neural.train.udim.build_training_stack`: those its bound meshes overlap, every tile on
disk for ``.mtlx`` input), and every measure reads uv inside them: the held-out error draws uv over
the trained tiles, the analytic views are rendered once per trained tile (the sphere's uv shifted to
the tile, :func:`mtlx2neural.render.udim_view.compare_tiles`; ``flip_per_view`` runs tile by tile,
``flip_per_tile`` holds each tile's mean, the PNGs are ``tile<UDIM>_view<i>_*.png``) and the in-scene
render reads the meshes' own uv, kept inside the trained tiles
(:class:`~mtlx2neural.render.udim_view.ClampToTiles`). Its analytic baseline has one map per trained
tile too.
"""

from __future__ import annotations

import dataclasses
import math
import os
import platform
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from mtlx2neural.atomic import atomic_path
from mtlx2neural.baseline.analytic_model import (
    BASELINE_FILE,
    fit_analytic,
    save_analytic,
)
from mtlx2neural.errors import InputError
from mtlx2neural.graph import compile_material
from mtlx2neural.graph.geometry import bind_geometry
from mtlx2neural.graph.ops import Application
from mtlx2neural.material_record import RECORD_FILE, MaterialRecord, write_record
from mtlx2neural.model.checkpoint import (
    checkpoint_file,
    model_from_checkpoint,
    read_checkpoint,
)
from mtlx2neural.pipeline.devices import device_name
from mtlx2neural.pipeline.in_scene_measure import measure_in_scene
from mtlx2neural.pipeline.plan import latent_resolution, scaled_grid
from mtlx2neural.pipeline.quality import viewer_warning
from mtlx2neural.reference import ReferenceMaterial
from mtlx2neural.reference.measured import MeasuredMaterial, load_measured
from mtlx2neural.render.flip_probe import FlipProbe
from mtlx2neural.render.renderer import save_png
from mtlx2neural.render.summary_views import describe as describe_views
from mtlx2neural.render.summary_views import (
    describe_viewer,
    summary_views,
    viewer_view,
    views_per_tile,
)
from mtlx2neural.textures.footprint import footprint_targets
from mtlx2neural.textures.parameter_stack import (
    ParameterStack,
    texture_resolution,
    uniform_stack,
)
from mtlx2neural.textures.surface_maps import (
    SURFACE_FILE,
    SurfaceMaps,
    build_surface_maps,
    load_surface_maps,
)
from mtlx2neural.train.config import PRESETS, TrainConfig
from mtlx2neural.train.directions import half_difference_pairs
from mtlx2neural.train.losses import log_l1
from mtlx2neural.train.trainer import Trainer
from mtlx2neural.train.udim import build_training_stack, draw_uv, is_udim_stack
from mtlx2neural.universal.canonical import canonical_document
from mtlx2neural.universal.fit import LayoutMismatch, fit_universal
from mtlx2neural.universal.weights import load_weights
from mtlx2neural.verify.energy import EnergyCheck, energy_check


def held_out_error(ref, model, stack, n: int = 8192, seed: int = 12345, surface: SurfaceMaps | None = None) -> float:
    """Log-L1 between the neural model at level 0 and the reference averaged over a level-0
    texel's footprint (the training target, up to 64 points), uv uniform (over the trained tiles of
    a UDIM ``stack``: a uniform tile, then a uniform point in it, as the training draws them; where a
    cut-out's ``surface`` has surface), half/difference directions, on draws the training never saw."""

    g = torch.Generator().manual_seed(seed)
    wi, wo = half_difference_pairs(n, g)
    uv = draw_uv(n, stack.tiles if is_udim_stack(stack) else None, g)
    if surface is not None and surface.partial and not is_udim_stack(stack):
        keep = surface.texel_covered(uv)
        if bool(keep.any()):
            wi, wo, uv = wi[keep], wo[keep], uv[keep]
            n = uv.shape[0]
    level = torch.zeros(n, dtype=torch.long)
    with torch.no_grad():
        target = footprint_targets(ref, stack, wi, wo, uv, level, 64, g) if stack.channels else ref.eval(wi, wo)
        return float(log_l1(model.eval(wi, wo, uv), target))



def measured_reference(src, device: str) -> tuple[MeasuredMaterial, ParameterStack]:
    """The reference and the (uniform, channel-less) training stack of a measured source's MERL table."""
    return load_measured(src.source_file, device=device), uniform_stack()


def train_material(src, cfg: TrainConfig, folder: Path, device: str, resume: bool, progress: bool,
                   allow_missing_textures: bool, digest: str, resolution: tuple[int, int] | None = None,
                   extra: dict | None = None, preview: bool = True, application: Application | None = None,
                   listener=None, encoder: dict | None = None) -> tuple:
    """Train one material into ``folder``; returns (model, :class:`MaterialRecord`) and writes the record
    (``summary.json``). ``listener(step, total, log record)``: called at every logged step (a pool
    worker's progress bar).

    ``application``: the instant ``time``/``frame`` nodes fold to (None: frame 1 at 24 fps); a graph
    that reads them records it in the record's ``application`` (frame, fps, time in seconds, nodes).

    ``resolution`` is the latent grid (default: :func:`mtlx2neural.pipeline.plan.latent_resolution`);
    ``extra``: values of further :class:`MaterialRecord` fields (hashes, options, planning warnings; its
    ``notes`` are put before the stack's). ``preview``:
    after training, also fit the analytic baseline of the layer's UsdPreviewSurface fallback
    (:func:`fit_preview`, ``cfg.preview_iterations`` steps, saved beside the checkpoint) and record its
    HDR FLIP (``preview_flip``, measured on the same renders as the neural model's ``flip_mean``);
    with ``cfg.preview_iterations = 0`` there is none (and no baseline file is left in ``folder``).

    A USD Material whose converted surface is its universal ``outputs:surface`` UsdPreviewSurface
    (:attr:`~mtlx2neural.scene.materials.MaterialSource.preview_surface`) keeps that shader as its fallback:
    nothing is fitted, and the record says so (:data:`OWN_PREVIEW`).

    ``encoder``: the universal path's choice (:mod:`mtlx2neural.universal.choice`): the material is compiled
    in its model's canonical form and its latents fit into the shipped network (:func:`mtlx2neural.universal.
    fit.fit_universal`); should its stack's layout not be the network's, it trains its own, with a note.
    """
    if encoder is not None:
        done = _fit_universal(src, cfg, folder, device, allow_missing_textures, digest, resolution, extra, preview,
                              application, progress, encoder)
        if not isinstance(done, str):
            return done
        extra = {**(extra or {}), "notes": [*(extra or {}).get("notes", []), done]}
    setup = prepare_material(src, cfg, folder, device, allow_missing_textures, resolution, preview, application)
    if resume:
        setup.trainer.resume()
    if progress:
        print(setup.describe(), flush=True)
    # FLIP against training time for the report (not for a UDIM stack: its views are per tile).
    probe = FlipProbe(setup.ref, tuple(setup.stack.resolution)) if not setup.tiles else None
    model = setup.trainer.run(progress=progress, listener=listener, probe=probe)
    return model, finish_material(setup, model, digest, extra)


@dataclass
class MaterialSetup:
    """One material ready to train: its reference, training stack, surface maps and trainer
    (:func:`prepare_material`), for :func:`finish_material` once the trainer has run."""

    src: object
    cfg: TrainConfig
    folder: Path
    device: str
    compiled: object
    """The :class:`~mtlx2neural.graph.compile.CompiledMaterial`; None for a measured table."""
    ref: object
    stack: object
    stack_notes: list[str]
    geometry_note: str | None
    surface: SurfaceMaps
    trainer: Trainer
    preview: bool
    """Fit the analytic baseline of the UsdPreviewSurface fallback after training."""
    t0: float
    own_preview: bool = False
    """The input's own UsdPreviewSurface is the fallback (:data:`OWN_PREVIEW`): nothing is fitted."""

    @property
    def tiles(self) -> list[int] | None:
        return list(self.stack.tiles) if is_udim_stack(self.stack) else None

    def describe(self) -> str:
        """The progress line announcing the training."""
        stack, cfg, tiles = self.stack, self.cfg, self.tiles
        return (f"{self.src.name}: {stack.resolution[1]}x{stack.resolution[0]} latent grid"
                f"{f' per UDIM tile, tiles {tiles}' if tiles else ''}, "
                f"{stack.levels[0].shape[0]} varying channels, decoder {cfg.decoder}, "
                f"{cfg.iterations} steps x {cfg.batch}")


def _fit_universal(src, cfg, folder, device, allow_missing_textures, digest, resolution, extra, preview,
                   application, progress, encoder: dict):
    """The universal path of :func:`train_material`: (model, record), or the note saying why not when the
    material's canonical stack is not the shipped network's layout."""
    setup = prepare_material(src, cfg, folder, device, allow_missing_textures, resolution, preview, application,
                             canonical=True)
    if progress:
        print(f"{src.name}: universal {encoder['model']} network, {encoder['steps']} fine-tune steps "
              f"({encoder['tune']})", flush=True)
    try:
        model = fit_universal(setup.trainer, load_weights(encoder["model"]), encoder["steps"], progress,
                              encoder["tune"])
    except LayoutMismatch as exc:
        return f"universal {encoder['model']} network not used ({exc}): trained its own"
    return model, finish_material(setup, model, digest, {**(extra or {}), "encoder": encoder})


def prepare_material(src, cfg: TrainConfig, folder: Path, device: str, allow_missing_textures: bool,
                     resolution: tuple[int, int] | None = None, preview: bool = True,
                     application: Application | None = None, canonical: bool = False) -> MaterialSetup:
    """Compile ``src`` (or read its MERL table), build its training stack and surface maps in ``folder``,
    and make its :class:`Trainer` (:func:`train_material` has the arguments). ``canonical``: compile the
    document's canonical form (:func:`mtlx2neural.universal.canonical.canonical_document`: the same BRDF,
    every input its shading model's universal encoder reads kept varying) for the stack and the surface maps;
    the reference is then the original program's (:func:`original_program`)."""
    t0 = time.time()
    folder.mkdir(parents=True, exist_ok=True)
    # An interrupted run must not leave an old record (and its hash) beside a new checkpoint.
    (folder / RECORD_FILE).unlink(missing_ok=True)
    own_preview = bool(preview and getattr(src, "preview_surface", False))  # the input's shader is exact
    preview = preview and cfg.preview_iterations > 0 and not own_preview
    if not preview:  # a baseline of an earlier run would otherwise be exported as this run's fallback
        (folder / BASELINE_FILE).unlink(missing_ok=True)
    compiled, ref, stack, stack_notes, geometry_note, surface = _build(src, cfg, device, allow_missing_textures,
                                                                       resolution, application, canonical)
    save_surface_maps(surface, folder)
    trainer = Trainer(ref, stack, cfg, folder, device=device, surface=surface)
    return MaterialSetup(src, cfg, folder, device, compiled, ref, stack, list(stack_notes), geometry_note, surface,
                         trainer, preview, t0, own_preview)


def row_trainer(src, cfg: TrainConfig, folder: Path, device: str, allow_missing_textures: bool,
                resolution: tuple[int, int] | None = None, application: Application | None = None,
                canonical: bool = False) -> Trainer:
    """A :class:`Trainer` built as :func:`prepare_material` builds it, writing nothing (``folder`` is only its
    name): one that draws training rows for the material in another process
    (:class:`~mtlx2neural.train.row_process.RowProcess`)."""
    _, ref, stack, _, _, surface = _build(src, cfg, device, allow_missing_textures, resolution, application,
                                          canonical)
    return Trainer(ref, stack, cfg, folder, device=device, surface=surface)


def _build(src, cfg, device, allow_missing_textures, resolution, application, canonical):
    """``src``'s compiled program (None for a MERL table), reference, training stack, its notes, the geometry
    note and its surface maps (not saved): :func:`prepare_material`'s work that writes nothing."""
    if getattr(src, "measured", False):  # a MERL table: its own reference, uniform, nothing beside the BRDF
        ref, stack = measured_reference(src, device)
        return None, ref, stack, [], None, SurfaceMaps()
    document = src.document
    if canonical:
        document = canonical_document(document, src.material)
    compiled = compile_material(document, src.material, device=device,
                                allow_missing_textures=allow_missing_textures, application=application)
    geometry_note = bind_geometry(compiled, getattr(src, "stage_file", None), src.bound_prims)
    stack, stack_notes = build_training_stack(compiled, getattr(src, "stage_file", None), src.bound_prims,
                                              resolution=resolution or latent_resolution(compiled, cfg))
    ref = ReferenceMaterial(compiled if not canonical else original_program(src, compiled, device,
                                                                              allow_missing_textures, application))
    return compiled, ref, stack, stack_notes, geometry_note, build_surface(compiled, stack, cfg, src.name)


def original_program(src, canonical, device: str, allow_missing_textures: bool, application):
    """The original document's program, for a material compiled in its canonical form (``canonical``): the
    same BRDF without the canonical form's zero-weight lobes, so its reference is the one the trainer's
    targets, the views and the measures evaluate (about half the time per evaluation). Its meshes are drawn
    at the canonical program's grid, the stack's."""
    original = compile_material(src.document, src.material, device=device,
                                allow_missing_textures=allow_missing_textures, application=application)
    bind_geometry(original, getattr(src, "stage_file", None), src.bound_prims)
    geometry = (original.evaluator.geometry, canonical.evaluator.geometry)
    if None not in geometry:
        geometry[0].resolution = geometry[1].resolution
    return original


def finish_material(setup: MaterialSetup, model, digest: str, extra: dict | None = None,
                    energy: bool = True) -> MaterialRecord:
    """After training: fit the preview fallback, render and measure the views (and the scene), check the
    energy, and write the material's record (``summary.json``), which it returns. ``energy=False``: no
    energy check, and the record is returned unwritten (the check runs elsewhere: :func:`energy_of`; the
    caller adds it with :func:`apply_energy`, then writes the record)."""
    src, cfg, folder, device = setup.src, setup.cfg, setup.folder, setup.device
    compiled, ref, stack, surface, trainer = setup.compiled, setup.ref, setup.stack, setup.surface, setup.trainer
    tiles, preview, t0 = setup.tiles, setup.preview, setup.t0
    stack_notes, geometry_note = setup.stack_notes, setup.geometry_note
    model.surface = surface
    train_seconds = time.time() - t0
    models = {"neural": model}
    if preview:  # a UDIM stack gives the baseline one map per tile too
        analytic, fit_seconds = fit_preview(ref, stack, folder, cfg.seed, cfg.preview_iterations,
                                            cfg.footprint_samples)
        analytic.surface = surface
        models["analytic"] = analytic
    # three directional views and one under the sky (render.summary_views); a UDIM material's once per
    # trained tile, the sphere's uv shifted into it
    renders = summary_views(ref, models, tuple(stack.resolution), tiles)
    errors, preview_errors = renders["neural"], renders.get("analytic")
    in_scene = measure_in_scene(ref, {"neural": model, **({"analytic": analytic} if preview else {})},
                                tuple(stack.resolution), src, folder)
    for i, e in enumerate(errors):
        name = f"tile{e['tile']}_view{i % views_per_tile()}" if tiles else f"view{i}"
        save_png(folder / f"{name}_reference.png", e["reference"])
        save_png(folder / f"{name}_neural.png", e["neural"])
        save_png(folder / f"{name}_flip.png", e["flip_map"], linear=False)
    viewer = None if tiles else viewer_view(ref, model, tuple(stack.resolution))
    if viewer is not None:  # the environment view as a viewer shades it (the node's prefiltered path)
        save_png(folder / "viewer_reference.png", viewer["reference"])
        save_png(folder / "viewer_neural.png", viewer["image"])
        save_png(folder / "viewer_flip.png", viewer["flip_map"], linear=False)
    extra = {**(extra or {}), **(OWN_PREVIEW if setup.own_preview else {})}
    record = MaterialRecord(
        material=src.name, mtlx_material=src.material, source=src.source_file, source_hash=digest,
        bound_prims=list(src.bound_prims), resolution=list(stack.resolution),
        varying_channels=int(stack.levels[0].shape[0]), decoder=cfg.decoder, config=dataclasses.asdict(cfg),
        steps=trainer.step, seconds=round(time.time() - t0, 1), train_seconds=round(train_seconds, 2),
        final_loss_brdf=trainer.history[-1]["loss_brdf"] if trainer.history else math.nan,
        held_out_log_l1=held_out_error(ref, model, stack, surface=surface), device=device, device_name=device_name(device),
        threads=torch.get_num_threads(), worker=f"{platform.node()}:{os.getpid()}",
        flip_per_view=[round(e["flip"], 4) for e in errors], flip_views=describe_views(),
        flip_mean=round(float(sum(e["flip"] for e in errors) / len(errors)), 4),
        surface={**surface.describe(), "refused": list(compiled.surface.refused) if compiled else []},
        relmse_mean=round(float(sum(e["relmse"] for e in errors) / len(errors)), 5),
        flip_viewer=None if viewer is None else round(viewer["flip"], 4),
        flip_viewer_view=describe_viewer() if viewer is not None else "",
        **in_scene,
        notes=list(extra.pop("notes", [])) + list(stack.notes) + list(stack_notes)
        + ([geometry_note] if geometry_note else []))
    if tiles:
        record.udim_tiles = tiles
        record.flip_per_tile = {str(t): round(float(sum(e["flip"] for e in errors if e["tile"] == t))
                                              / sum(1 for e in errors if e["tile"] == t), 4) for t in tiles}
    if preview:
        record = dataclasses.replace(record, **preview_record(preview_errors, fit_seconds, cfg.preview_iterations))
    if compiled is not None and compiled.reads_application:
        app = compiled.application
        record.application = {"frame": app.frame, "fps": app.fps, "time": app.time,
                               "nodes": list(compiled.reads_application)}
    record = dataclasses.replace(record, **extra)
    flip_notes = sorted({f"view {e['view']}: {e['flip_note']}" for e in errors if e.get("flip_note")})
    if flip_notes:  # a black reference view (cut-out, unlit): the figure is defined, not the usual one
        record.warnings = [*record.warnings, *(f"HDR FLIP: {n}" for n in flip_notes)]
    viewer_note = viewer_warning(record)
    if viewer_note:
        record.warnings = [*record.warnings, viewer_note]
    if not energy:
        return record
    record = with_energy(record, ref, model, stack, device, surface)
    write_record(folder, record)
    return record




def finish_from_checkpoint(src, cfg: TrainConfig, folder: Path, device: str, allow_missing_textures: bool,
                           digest: str, resolution, extra: dict, application: Application | None = None,
                           canonical: bool = False, trained_seconds: float = 0.0, part: str | None = None):
    """Measure and record a material whose model is already trained and saved in ``folder``'s checkpoint
    (a ``--network scene`` group's, trained in another process): prepare it as its training did
    (:func:`prepare_material`, ``cfg`` the one it trained with), read the model, its step and its
    history from the checkpoint, then :func:`finish_material`. ``trained_seconds``: the training's wall
    time (the record's ``train_seconds``; its ``seconds`` adds this material's measures).

    ``part`` splits the work in two, for two processes: ``"energy"`` returns the energy check alone
    (:func:`energy_of`, nothing written), ``"record"`` the record without it, unwritten
    (``finish_material(..., energy=False)``); None does both and writes the record."""
    f = checkpoint_file(folder)
    ck = read_checkpoint(f, device)
    if part == "energy":
        _, ref, stack, _, _, surface = _build(src, cfg, device, allow_missing_textures, resolution, application,
                                              canonical)
        return energy_of(ref, model_from_checkpoint(ck, f, device), stack, device, surface)
    setup = prepare_material(src, cfg, folder, device, allow_missing_textures, resolution,
                             application=application, canonical=canonical)
    setup.trainer.step, setup.trainer.history = ck["step"], list(ck["history"])
    setup.t0 = time.time() - trained_seconds
    return finish_material(setup, model_from_checkpoint(ck, f, device), digest, extra, energy=part != "record")


def save_surface_maps(maps: SurfaceMaps, folder: Path) -> None:
    """Save ``maps`` as ``folder/surface_maps.pt``, or remove that file when there are none."""
    path = folder / SURFACE_FILE
    path.unlink(missing_ok=True)
    if not maps.empty:
        with atomic_path(path) as tmp:
            torch.save(maps.state(), tmp)


def build_surface(compiled, stack, cfg: TrainConfig, name: str) -> SurfaceMaps:
    """The emission and opacity maps on the latent grid (:mod:`mtlx2neural.textures.surface_maps`). A
    uniform BRDF with a textured emission or opacity gets maps on its textures' grid (capped by
    ``cfg.max_resolution``); a UDIM material with one is refused (``InputError``): its maps would need one
    pyramid per tile."""
    kinds = compiled.describe_surface()
    textured = "textured" in (kinds["emission"], kinds["opacity"])
    if textured and is_udim_stack(stack):
        raise InputError(f"{name}: a UDIM material whose emission or opacity reads a texture is not supported "
                         f"(its maps would need one pyramid per tile); bake them into one texture set")
    resolution, ratio = tuple(stack.resolution), stack.texel_ratio
    if textured and resolution == (1, 1):
        h, w, _ = texture_resolution(compiled)
        side = min(max(h, w), cfg.max_resolution or max(h, w))
        resolution, ratio = scaled_grid(h, w, side), (1.0, 1.0)
    return build_surface_maps(compiled, resolution, ratio) if not is_udim_stack(stack) else SurfaceMaps()


ENERGY_WARNING = 0.9
"""An energy ratio below this at any MIP level (the neural model reflects less than 90 % of the
reference's directional albedo there) puts a warning in the record: the material renders darker."""
ENERGY_WARNING_BRIGHT = 1.2
"""An energy ratio above this at any MIP level puts a warning in the record: the material renders
brighter (the near-mirror sample's 1.08-1.35; the reference against itself stays within 1.00-1.03)."""


def with_energy(record: MaterialRecord, ref, model, stack, device, surface: SurfaceMaps | None = None
                ) -> MaterialRecord:
    """``record`` with the energy check (:mod:`mtlx2neural.verify.energy`, 64 texels x 4 views per level,
    a few seconds) and a warning when a level keeps less than :data:`ENERGY_WARNING` of the energy or
    more than :data:`ENERGY_WARNING_BRIGHT`.
    A cut-out (``surface`` with coverage below 1) is checked where it has surface, as it trains.
    A UDIM material is not checked (its levels are per tile): a note says so."""
    return apply_energy(record, energy_of(ref, model, stack, device, surface))


def energy_of(ref, model, stack, device, surface: SurfaceMaps | None = None) -> EnergyCheck | None:
    """The energy check of :func:`with_energy` (None for a UDIM material)."""
    if is_udim_stack(stack):
        return None
    return energy_check(ref, model, tuple(stack.resolution), len(model.latents.levels), device=device,
                        params_at=stack.native_params_at(),
                        coverage=surface.coverage_at if surface is not None and surface.partial else None)


def apply_energy(record: MaterialRecord, check: EnergyCheck | None) -> MaterialRecord:
    """``record`` with the energy check's figures and warnings (:func:`with_energy`; None: a UDIM material's
    note)."""
    if check is None:
        return dataclasses.replace(record, notes=[*record.notes, "energy check: not measured for a UDIM material"])
    record = dataclasses.replace(record, energy=check.to_json())
    longer = train_longer(record.config.get("iterations") if record.config else None)
    if check.min_ratio < ENERGY_WARNING:
        record = record.with_warning(
            f"the neural model keeps {check.min_ratio:.0%} of the reference's directional albedo at MIP level "
            f"{check.worst_level} (energy check; under {ENERGY_WARNING:.0%} renders visibly darker): {longer}")
    if check.max_ratio > ENERGY_WARNING_BRIGHT:
        record = record.with_warning(
            f"the neural model reflects {check.max_ratio:.0%} of the reference's directional albedo at MIP level "
            f"{check.brightest_level} (energy check; over {ENERGY_WARNING_BRIGHT:.0%} renders visibly brighter): "
            f"{longer}")
    return record


def train_longer(iterations: int | None) -> str:
    """The advice to train longer for a material trained ``iterations`` steps: the standard preset when it
    trained fewer steps than that, else more steps than it had."""
    standard = PRESETS["standard"].iterations
    if iterations is None or iterations < standard:
        return "train longer (--preset standard)"
    return f"train longer (--iterations over {iterations})"


PREVIEW_ITERATIONS = TrainConfig.preview_iterations
"""Default Adam steps of the analytic baseline behind the UsdPreviewSurface fallback (batch
:data:`PREVIEW_BATCH`; a run takes ``TrainConfig.preview_iterations``, 100 in the fast preset).
Measured on the samples (2 shared CPU cores, one torch thread): 200 steps reach the 300-step
default's HDR FLIP within 0.002 (CarPaint 0.088 / 0.087, Plastic 0.028 / 0.027) in about a third of
its time."""
PREVIEW_BATCH = 2048


def fit_preview(ref, stack, folder: Path, seed: int = 0, iterations: int = PREVIEW_ITERATIONS,
                footprint_points: int = TrainConfig.footprint_samples):
    """Fit the analytic baseline (Lambert + GGX, :func:`~mtlx2neural.baseline.analytic_model.fit_analytic`,
    ``iterations`` Adam steps, targets averaged over ``footprint_points`` points at most, as the run's
    ``footprint_samples``) to ``ref`` on ``stack``'s grid and save it as ``folder/analytic_baseline.pt``;
    returns (model, seconds the fit took).

    The fast preset's 8 points instead of 16 fit 1.3-1.8x faster at a preview HDR FLIP within 2 %
    (chess ``M_Bishop_B`` at 64² 0.150 / 0.153, ``M_Queen_B`` 0.286 / 0.289, GlazedCeramic 0.162 / 0.163,
    BrushedMetal 0.441 / 0.442, ``standard_surface_wood_tiled`` 0.288 / 0.287; 2026-12-06)."""
    t0 = time.time()
    analytic = fit_analytic(ref, stack, iterations=iterations, batch=PREVIEW_BATCH, seed=seed,
                            max_samples=footprint_points)
    save_analytic(analytic, folder / BASELINE_FILE)
    return analytic, time.time() - t0


def preview_record(errors: list[dict], fit_seconds: float, iterations: int = PREVIEW_ITERATIONS) -> dict:
    """The record's ``preview_flip`` (mean HDR FLIP of the analytic baseline against the reference
    over the views, as ``flip_mean`` for the neural model) and ``preview`` (per view, fit seconds)."""
    flips = [e["flip"] for e in errors]
    return {"preview_flip": round(float(sum(flips) / len(flips)), 4),
            "preview": {"model": "analytic Lambert + GGX (UsdPreviewSurface fallback)", "file": BASELINE_FILE,
                        "iterations": iterations, "flip_per_view": [round(f, 4) for f in flips],
                        "fit_seconds": round(fit_seconds, 2)}}


OWN_PREVIEW = {"preview_flip": 0.0, "preview": {"model": "the input's own UsdPreviewSurface (exact, not fitted)",
                                                "own": True, "file": None, "iterations": 0}}
"""The record's preview fields for a material whose input shader is its own fallback: it is the reference,
so its HDR FLIP against it is 0 (the layer leaves the Material's ``outputs:surface`` as the input has it)."""


def add_preview(src, folder: Path, device: str, allow_missing_textures: bool, resolution, seed: int,
                record: MaterialRecord, iterations: int = PREVIEW_ITERATIONS,
                application: Application | None = None,
                footprint_points: int = TrainConfig.footprint_samples) -> MaterialRecord:
    """Fit (``iterations`` steps), save and measure the preview baseline for a material trained without
    it (the chosen decoder of an error budget, :func:`~mtlx2neural.pipeline.budget.train_within_budget`);
    returns ``record`` with the fit's figures (with :data:`OWN_PREVIEW`'s and no fit for an input whose own
    shader is the fallback)."""
    if getattr(src, "preview_surface", False):
        return dataclasses.replace(record, **OWN_PREVIEW)
    if getattr(src, "measured", False):
        ref, stack = measured_reference(src, device)
    else:
        compiled = compile_material(src.document, src.material, device=device,
                                    allow_missing_textures=allow_missing_textures, application=application)
        bind_geometry(compiled, getattr(src, "stage_file", None), src.bound_prims)
        ref = ReferenceMaterial(compiled)
        stack, _ = build_training_stack(compiled, getattr(src, "stage_file", None), src.bound_prims,
                                        resolution=tuple(resolution))
    analytic, seconds = fit_preview(ref, stack, folder, seed, iterations, footprint_points)
    analytic.surface = load_surface_maps(folder / SURFACE_FILE)  # the emission and opacity it is shown with
    tiles = list(stack.tiles) if is_udim_stack(stack) else None
    errors = summary_views(ref, {"analytic": analytic}, tuple(stack.resolution), tiles)["analytic"]
    scene = measure_in_scene(ref, {"analytic": analytic}, tuple(stack.resolution), src)
    return dataclasses.replace(record, **preview_record(errors, seconds, iterations),
                               preview_flip_in_scene=scene.get("preview_flip_in_scene"))

