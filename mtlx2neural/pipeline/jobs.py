"""Per-material training jobs: one :class:`MaterialJob` per material, run by :func:`run_job`.

Training one material is independent of training another, so every material is one
picklable :class:`MaterialJob` (its MaterialX document travels as XML; documents do not
pickle), run by one function, :func:`run_job`, wherever it runs: in this process, a
spawned pool worker or a Ray task (:mod:`mtlx2neural.pipeline.workers` decides where). A
job writes its results into its material folder (``checkpoint.pt``,
``training_curves.csv``, ``summary.json``, PNGs, and the analytic baseline fitted for the
layer's UsdPreviewSurface fallback, ``analytic_baseline.pt``: :func:`train_material`). With an error
budget (``max_error``) it trains decoders from small to large until the HDR FLIP meets
the budget (:func:`choose_decoder`).

Fidelity is measured twice for a USD source whose material is bound to meshes: on the analytic
views (``flip_mean``: the unit sphere, three views, :func:`~mtlx2neural.render.renderer.compare`)
and in the scene (``flip_in_scene``: the bound meshes, the stage's camera and lights,
:mod:`mtlx2neural.render.in_scene`, recorded with how it was viewed and lit in ``in_scene``). The
error budget uses the in-scene figure when there is one (:func:`budget_error`), the analytic one
otherwise (``.mtlx`` input, or a stage whose bound prims give no triangles).

A UDIM material (its graph reads a ``<UDIM>`` texture set) trains only its tiles
(:func:`mtlx2neural.train.udim.build_training_stack`: those its bound meshes overlap, every tile on
disk for ``.mtlx`` input), and every measure reads uv inside them: the held-out error draws uv over
the trained tiles, the analytic views are rendered once per trained tile (the sphere's uv shifted to
the tile, :func:`mtlx2neural.render.udim_view.compare_tiles`; ``flip_per_view`` runs tile by tile,
``flip_per_tile`` holds each tile's mean, the PNGs are ``tile<UDIM>_view<i>_*.png``) and the in-scene
render reads the meshes' own uv, kept inside the trained tiles
(:class:`~mtlx2neural.render.udim_view.ClampToTiles`). Its analytic baseline (the UsdPreviewSurface
fallback) has one map per trained tile too.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import platform
import shutil
import tempfile
import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import torch

from mtlx2neural.atomic import atomic_path
from mtlx2neural.baseline.analytic_model import (
    BASELINE_FILE,
    fit_analytic,
    save_analytic,
)
from mtlx2neural.errors import InputError, Mtlx2NeuralError
from mtlx2neural.faults import fault_point
from mtlx2neural.graph import compile_material
from mtlx2neural.graph.geometry import bind_geometry
from mtlx2neural.graph.ops import Application
from mtlx2neural.pipeline.plan import DECODERS, latent_resolution
from mtlx2neural.pipeline.source_hash import input_hash
from mtlx2neural.reference import ReferenceMaterial
from mtlx2neural.render.flip_probe import FlipProbe
from mtlx2neural.render.in_scene import compare_in_scene, stage_in_scene
from mtlx2neural.render.renderer import compare_many, save_png
from mtlx2neural.render.udim_view import ClampToTiles, compare_tiles, model_tiles
from mtlx2neural.scene import MaterialSource
from mtlx2neural.textures.footprint import footprint_targets
from mtlx2neural.train.config import TrainConfig
from mtlx2neural.train.directions import half_difference_pairs
from mtlx2neural.train.losses import log_l1
from mtlx2neural.train.trainer import Trainer
from mtlx2neural.train.udim import build_training_stack, draw_uv, is_udim_stack

# ----------------------------------------------------------------------------- the error budget


def choose_decoder(train_and_measure: Callable[[str], float], budget: float,
                   sizes: tuple[str, ...] = DECODERS) -> tuple[str, dict[str, float]]:
    """The smallest decoder of ``sizes`` whose error meets ``budget``.

    ``train_and_measure(decoder)`` trains that size and returns its error (HDR FLIP
    mean); sizes are tried smallest first and the search stops at the first whose
    error is <= ``budget``. When none meets it, the one with the lowest error (the
    smaller on a tie) is returned. A non-finite error never meets a budget. Returns
    ``(decoder, {decoder tried: error})``; the budget was met iff
    ``errors[decoder] <= budget``.
    """
    errors: dict[str, float] = {}
    for size in sizes:
        err = float(train_and_measure(size))
        errors[size] = err
        if math.isfinite(err) and err <= budget:
            return size, errors
    finite = {k: v for k, v in errors.items() if math.isfinite(v)}
    best = min(finite, key=lambda k: (finite[k], sizes.index(k))) if finite else sizes[-1]
    return best, errors


# ----------------------------------------------------------------------------- one material


def held_out_error(ref, model, stack, n: int = 8192, seed: int = 12345) -> float:
    """Log-L1 between the neural model at level 0 and the reference averaged over a level-0
    texel's footprint (the training target, up to 64 points), uv uniform (over the trained tiles of
    a UDIM ``stack``: a uniform tile, then a uniform point in it, as the training draws them),
    half/difference directions, on draws the training never saw."""

    g = torch.Generator().manual_seed(seed)
    wi, wo = half_difference_pairs(n, g)
    uv = draw_uv(n, stack.tiles if is_udim_stack(stack) else None, g)
    level = torch.zeros(n, dtype=torch.long)
    with torch.no_grad():
        target = footprint_targets(ref, stack, wi, wo, uv, level, 64, g) if stack.channels else ref.eval(wi, wo)
        return float(log_l1(model.eval(wi, wo, uv), target))


def device_name(device: str) -> str:
    """``cpu (x86_64)`` or ``cuda:0 (<GPU name>)``: where the training ran, for the metrics."""
    if device.startswith("cuda") and torch.cuda.is_available():
        d = torch.device(device)
        return f"cuda:{d.index or 0} ({torch.cuda.get_device_name(d)})"
    return f"{device} ({platform.machine() or 'unknown'})"


def resolve_device(device: str) -> str:
    """``auto`` -> ``cuda`` when CUDA is available, else ``cpu``; anything else unchanged."""
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    return device


def check_device(device: str) -> str:
    """``device`` resolved (:func:`resolve_device`), or :class:`~mtlx2neural.errors.InputError`
    when it is not ``auto``, ``cpu``, ``cuda`` or ``cuda:N`` of a GPU this machine has."""
    try:
        d = torch.device(resolve_device(device))
    except (RuntimeError, TypeError):
        d = None
    if d is None or d.type not in ("cpu", "cuda"):
        raise InputError(f"--device {device!r}: not a device mtlx2neural trains on; give cpu, cuda, cuda:N or auto")
    if d.type == "cuda":
        if not torch.cuda.is_available():
            build = f"CUDA {torch.version.cuda}" if torch.version.cuda else "no CUDA (a CPU build)"
            raise InputError(f"--device {device}: CUDA is not available on this machine (torch {torch.__version__} "
                             f"has {build}); use --device cpu, or auto to take a GPU when there is one")
        if d.index is not None and d.index >= torch.cuda.device_count():
            raise InputError(f"--device {device}: this machine has {torch.cuda.device_count()} CUDA device(s), "
                             f"numbered from 0")
    return str(d)


IN_SCENE_KEYS = {"neural": "flip_in_scene", "analytic": "preview_flip_in_scene"}
"""Summary key of each model's in-scene HDR FLIP."""


def measure_in_scene(ref, models: dict, texels: tuple[int, int], src, folder: Path | None = None) -> dict:
    """The summary's in-scene entries for ``models`` (labels ``neural`` and/or ``analytic``) on the meshes
    ``src`` is bound to, with its stage's camera and lights (:mod:`mtlx2neural.render.in_scene`):
    ``flip_in_scene`` / ``preview_flip_in_scene`` (HDR FLIP over the pixels that show the meshes) and
    ``in_scene`` (camera, lights, prims, triangles, resolution, samples, the whole-image FLIP, coverage,
    seconds, notes). ``{}`` for a source without a stage file or bound prims (``.mtlx``); when the stage
    gives nothing to render, or reading it fails, ``in_scene`` says why and there is no figure.
    ``folder``: also write ``in_scene_reference.png``, ``in_scene_<label>.png`` and ``in_scene_flip.png``."""
    stage_file = getattr(src, "stage_file", None)
    if not stage_file or not src.bound_prims:
        return {}
    try:
        scene = stage_in_scene(stage_file, src.bound_prims)
        if isinstance(scene, str):
            return {"in_scene": {"measured": False, "why": scene}}
        # a UDIM model reads the meshes' own uv, kept inside its trained tiles (edge points move)
        models = {label: ClampToTiles(m, model_tiles(m)) if model_tiles(m) else m for label, m in models.items()}
        results = compare_in_scene(ref, models, texels, scene)
    except (Mtlx2NeuralError, OSError, ValueError, RuntimeError) as exc:  # a measure never fails the training
        return {"in_scene": {"measured": False, "why": f"{type(exc).__name__}: {exc}"}}
    first = results[next(iter(results))]
    if not math.isfinite(first["flip"]):  # every pixel black in every render: back faces, or no light above
        return {"in_scene": {"measured": False, **scene.record,
                             "why": "the in-scene render shows nothing lit (back faces, or every light below the "
                                    "surfaces' horizon)"}}
    out = {IN_SCENE_KEYS.get(label, f"{label}_flip_in_scene"): round(r["flip"], 4) for label, r in results.items()}
    out["in_scene"] = {"measured": True, **scene.record, "res": first["res"], "spp": first["spp"],
                       "coverage": first["coverage"],
                       "flip_image": {label: round(r["flip_image"], 4) for label, r in results.items()},
                       "seconds": {label: r["seconds"] for label, r in results.items()}}
    if folder is not None:
        save_png(folder / "in_scene_reference.png", first["reference"])
        for label, r in results.items():
            save_png(folder / f"in_scene_{label}.png", r[label])
        save_png(folder / "in_scene_flip.png", first["flip_map"], linear=False)
    return out


def budget_error(summary: dict) -> float:
    """The HDR FLIP an error budget (``--max-error``) is checked against: ``flip_in_scene`` when the
    summary has one (a USD source bound to meshes), else ``flip_mean`` (the analytic views)."""
    return summary["flip_in_scene"] if summary.get("flip_in_scene") is not None else summary["flip_mean"]


def write_summary(folder: Path, summary: dict) -> None:
    """Write ``folder/summary.json`` atomically."""
    with atomic_path(folder / "summary.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=2))


def train_material(src, cfg: TrainConfig, folder: Path, device: str, resume: bool, progress: bool,
                   allow_missing_textures: bool, digest: str, resolution: tuple[int, int] | None = None,
                   extra: dict | None = None, preview: bool = True, application: Application | None = None):
    """Train one material into ``folder``; returns (model, summary) and writes ``summary.json``.

    ``application``: the instant ``time``/``frame`` nodes fold to (None: frame 1 at 24 fps); a graph
    that reads them records it in the summary's ``application`` (frame, fps, time in seconds, nodes).

    ``resolution`` is the latent grid (default: :func:`mtlx2neural.pipeline.plan.latent_resolution`);
    ``extra`` is merged into the summary (its ``notes`` are put before the stack's). ``preview``:
    after training, also fit the analytic baseline of the layer's UsdPreviewSurface fallback
    (:func:`fit_preview`, ``cfg.preview_iterations`` steps, saved beside the checkpoint) and record its
    HDR FLIP (``preview_flip``, measured on the same renders as the neural model's ``flip_mean``);
    with ``cfg.preview_iterations = 0`` there is none (and no baseline file is left in ``folder``).
    """

    t0 = time.time()
    folder.mkdir(parents=True, exist_ok=True)
    # An interrupted run must not leave an old summary (and its hash) beside a new checkpoint.
    (folder / "summary.json").unlink(missing_ok=True)
    preview = preview and cfg.preview_iterations > 0
    if not preview:  # a baseline of an earlier run would otherwise be exported as this run's fallback
        (folder / BASELINE_FILE).unlink(missing_ok=True)
    compiled = compile_material(src.document, src.material, device=device,
                                allow_missing_textures=allow_missing_textures, application=application)
    geometry_note = bind_geometry(compiled, getattr(src, "stage_file", None), src.bound_prims)
    ref = ReferenceMaterial(compiled)
    stack, stack_notes = build_training_stack(compiled, getattr(src, "stage_file", None), src.bound_prims,
                                              resolution=resolution or latent_resolution(compiled, cfg))
    tiles = list(stack.tiles) if is_udim_stack(stack) else None
    trainer = Trainer(ref, stack, cfg, folder, device=device)
    if resume:
        trainer.resume()
    if progress:
        print(f"{src.name}: {stack.resolution[1]}x{stack.resolution[0]} latent grid"
              f"{f' per UDIM tile, tiles {tiles}' if tiles else ''}, "
              f"{stack.levels[0].shape[0]} varying channels, decoder {cfg.decoder}, "
              f"{cfg.iterations} steps x {cfg.batch}", flush=True)
    # FLIP against training time for the report (not for a UDIM stack: its views are per tile).
    probe = FlipProbe(ref, tuple(stack.resolution)) if not tiles else None
    model = trainer.run(progress=progress, listener=_LISTENER, probe=probe)
    train_seconds = time.time() - t0
    models = {"neural": model}
    if preview:  # a UDIM stack gives the baseline one map per tile too
        analytic, fit_seconds = fit_preview(ref, stack, folder, cfg.seed, cfg.preview_iterations)
        models["analytic"] = analytic
    if tiles:  # the sphere's uv shifted into each trained tile: the views once per tile
        renders = compare_tiles(ref, models, tuple(stack.resolution), tiles)
    else:  # without the baseline, the same renders as compare(..., label="neural")
        renders = compare_many(ref, models, texels=tuple(stack.resolution))
    errors, preview_errors = renders["neural"], renders.get("analytic")
    in_scene = measure_in_scene(ref, {"neural": model, **({"analytic": analytic} if preview else {})},
                                tuple(stack.resolution), src, folder)
    for i, e in enumerate(errors):
        name = f"tile{e['tile']}_view{i % (len(errors) // len(tiles))}" if tiles else f"view{i}"
        save_png(folder / f"{name}_reference.png", e["reference"])
        save_png(folder / f"{name}_neural.png", e["neural"])
        save_png(folder / f"{name}_flip.png", e["flip_map"], linear=False)
    extra = dict(extra or {})
    summary = {"material": src.name, "mtlx_material": src.material, "source": src.source_file,
               "bound_prims": list(src.bound_prims), "source_hash": digest,
               "resolution": list(stack.resolution), "varying_channels": int(stack.levels[0].shape[0]),
               "decoder": cfg.decoder, "config": dataclasses.asdict(cfg),
               "steps": trainer.step, "seconds": round(time.time() - t0, 1),
               "train_seconds": round(train_seconds, 2),
               "final_loss_brdf": trainer.history[-1]["loss_brdf"] if trainer.history else math.nan,
               "held_out_log_l1": held_out_error(ref, model, stack), "device": device,
               "device_name": device_name(device), "threads": torch.get_num_threads(),
               "worker": f"{platform.node()}:{os.getpid()}",
               "flip_per_view": [round(e["flip"], 4) for e in errors],
               "flip_mean": round(float(sum(e["flip"] for e in errors) / len(errors)), 4),
               "relmse_mean": round(float(sum(e["relmse"] for e in errors) / len(errors)), 5),
               **in_scene,
               "notes": list(extra.pop("notes", [])) + list(stack.notes) + list(stack_notes)
               + ([geometry_note] if geometry_note else [])}
    if tiles:
        summary["udim_tiles"] = tiles
        summary["flip_per_tile"] = {str(t): round(float(sum(e["flip"] for e in errors if e["tile"] == t))
                                                  / sum(1 for e in errors if e["tile"] == t), 4) for t in tiles}
    if preview:
        summary.update(preview_record(preview_errors, fit_seconds, cfg.preview_iterations))
    if compiled.reads_application:
        app = compiled.application
        summary["application"] = {"frame": app.frame, "fps": app.fps, "time": app.time,
                                   "nodes": list(compiled.reads_application)}
    summary.update(extra)
    flip_notes = sorted({f"view {e['view']}: {e['flip_note']}" for e in errors if e.get("flip_note")})
    if flip_notes:  # a black reference view (cut-out, unlit): the figure is defined, not the usual one
        summary["warnings"] = list(summary.get("warnings", [])) + [f"HDR FLIP: {n}" for n in flip_notes]
    write_summary(folder, summary)
    return model, summary


PREVIEW_ITERATIONS = TrainConfig.preview_iterations
"""Default Adam steps of the analytic baseline behind the UsdPreviewSurface fallback (batch
:data:`PREVIEW_BATCH`; a run takes ``TrainConfig.preview_iterations``, 100 in the fast preset).
Measured on the samples (2 shared CPU cores, one torch thread): 200 steps reach the 300-step
default's HDR FLIP within 0.002 (CarPaint 0.088 / 0.087, Plastic 0.028 / 0.027) in about a third of
its time."""
PREVIEW_BATCH = 2048


def fit_preview(ref, stack, folder: Path, seed: int = 0, iterations: int = PREVIEW_ITERATIONS):
    """Fit the analytic baseline (Lambert + GGX, :func:`~mtlx2neural.baseline.analytic_model.fit_analytic`,
    ``iterations`` Adam steps) to ``ref`` on ``stack``'s grid and save it as
    ``folder/analytic_baseline.pt``; returns (model, seconds the fit took)."""
    t0 = time.time()
    analytic = fit_analytic(ref, stack, iterations=iterations, batch=PREVIEW_BATCH, seed=seed)
    save_analytic(analytic, folder / BASELINE_FILE)
    return analytic, time.time() - t0


def preview_record(errors: list[dict], fit_seconds: float, iterations: int = PREVIEW_ITERATIONS) -> dict:
    """The summary's ``preview_flip`` (mean HDR FLIP of the analytic baseline against the reference
    over the views, as ``flip_mean`` for the neural model) and ``preview`` (per view, fit seconds)."""
    flips = [e["flip"] for e in errors]
    return {"preview_flip": round(float(sum(flips) / len(flips)), 4),
            "preview": {"model": "analytic Lambert + GGX (UsdPreviewSurface fallback)", "file": BASELINE_FILE,
                        "iterations": iterations, "flip_per_view": [round(f, 4) for f in flips],
                        "fit_seconds": round(fit_seconds, 2)}}


def add_preview(src, folder: Path, device: str, allow_missing_textures: bool, resolution, seed: int,
                summary: dict, iterations: int = PREVIEW_ITERATIONS,
                application: Application | None = None) -> dict:
    """Fit (``iterations`` steps), save and measure the preview baseline for a material trained without
    it (the chosen decoder of an error budget, :func:`train_within_budget`); returns ``summary`` with
    its record."""
    compiled = compile_material(src.document, src.material, device=device,
                                allow_missing_textures=allow_missing_textures, application=application)
    bind_geometry(compiled, getattr(src, "stage_file", None), src.bound_prims)
    ref = ReferenceMaterial(compiled)
    stack, _ = build_training_stack(compiled, getattr(src, "stage_file", None), src.bound_prims,
                                    resolution=tuple(resolution))
    analytic, seconds = fit_preview(ref, stack, folder, seed, iterations)
    if is_udim_stack(stack):
        errors = compare_tiles(ref, {"analytic": analytic}, tuple(stack.resolution), list(stack.tiles))["analytic"]
    else:
        errors = compare_many(ref, {"analytic": analytic}, texels=tuple(stack.resolution))["analytic"]
    scene = measure_in_scene(ref, {"analytic": analytic}, tuple(stack.resolution), src)
    extra = {"preview_flip_in_scene": scene["preview_flip_in_scene"]} if "preview_flip_in_scene" in scene else {}
    return {**summary, **preview_record(errors, seconds, iterations), **extra}


BUDGET_FOLDER = "budget"
"""Sub-folder of a material folder where the decoder sizes of an error budget train."""


def train_within_budget(src, cfg: TrainConfig, folder: Path, device: str, resume: bool, progress: bool,
                        allow_missing_textures: bool, digest: str, max_error: float,
                        resolution: tuple[int, int] | None = None, extra: dict | None = None,
                        application: Application | None = None) -> dict:
    """Train the smallest decoder of :data:`~mtlx2neural.pipeline.plan.DECODERS` whose HDR FLIP is at
    most ``max_error`` (:func:`choose_decoder`); returns its summary. The FLIP is the in-scene one when
    the source's stage gives one, else the analytic views' mean (:func:`budget_error`).

    Each size trains into ``folder/budget/<size>/``; the chosen one's files then move up
    into ``folder`` and the others are deleted. The summary adds ``budget`` (the budget,
    the FLIP and seconds of every size tried, and ``metric``: which figure was checked,
    ``flip_in_scene`` or ``flip_mean``) and ``budget_met``; a missed budget is
    also a warning in ``warnings`` and ``notes``.
    """
    (folder / "summary.json").unlink(missing_ok=True)
    runs: dict[str, dict] = {}

    def attempt(decoder: str) -> float:
        sub = folder / BUDGET_FOLDER / decoder
        _, s = train_material(src, dataclasses.replace(cfg, decoder=decoder), sub, device, resume, progress,
                              allow_missing_textures, digest, resolution, extra, preview=False,
                              application=application)
        runs[decoder] = s
        err = budget_error(s)
        if progress:
            where = "in scene" if s.get("flip_in_scene") is not None else "analytic views"
            print(f"{src.name}: decoder {decoder}: HDR FLIP {err:.4f} ({where}; "
                  f"{'meets' if err <= max_error else 'misses'} the budget {max_error})", flush=True)
        return err

    decoder, flips = choose_decoder(attempt, max_error)
    met = bool(flips[decoder] <= max_error)
    for p in (folder / BUDGET_FOLDER / decoder).iterdir():
        os.replace(p, folder / p.name)
    shutil.rmtree(folder / BUDGET_FOLDER, ignore_errors=True)
    summary = dict(runs[decoder])
    if cfg.preview_iterations > 0:
        summary = add_preview(src, folder, device, allow_missing_textures, runs[decoder]["resolution"], cfg.seed,
                              summary, cfg.preview_iterations, application)
    else:
        (folder / BASELINE_FILE).unlink(missing_ok=True)
    summary["budget"] = {"max_error": max_error, "flip_by_decoder": flips,
                         "metric": "flip_in_scene" if runs[decoder].get("flip_in_scene") is not None else "flip_mean",
                         "seconds_by_decoder": {k: v["seconds"] for k, v in runs.items()}, "met": met}
    summary["budget_met"] = met
    summary["seconds"] = round(sum(v["seconds"] for v in runs.values()), 1)
    if not met:
        warning = (f"HDR FLIP budget {max_error} not met: even the largest decoder, {DECODERS[-1]}, reaches "
                   f"{flips[DECODERS[-1]]:.4f}; kept {decoder} ({flips[decoder]:.4f}). Train longer "
                   f"(--preset standard on a CPU, balanced on a GPU, or --iterations) or relax --max-error")
        summary["warnings"] = list(summary.get("warnings", [])) + [warning]
        summary["notes"] = [warning] + list(summary.get("notes", []))
    write_summary(folder, summary)
    return summary


@dataclass
class MaterialJob:
    """Everything one material's training needs; picklable (for process pools and Ray)."""

    name: str
    """Material name (prim path or MaterialX name), as ``MaterialSource.name``."""
    material: str
    """The surfacematerial node in the document."""
    source_file: str
    bound_prims: list[str]
    document_xml: str
    """The material's MaterialX document as XML (``filename`` values are absolute)."""
    folder: str
    """The material's output folder."""
    cfg: TrainConfig
    digest: str
    """Cache key stored as ``source_hash``."""
    content: str
    """Name-free content hash, stored as ``content_hash``."""
    resolution: tuple[int, int]
    """Latent grid (H, W) from the plan."""
    device: str = "auto"
    resume: bool = False
    progress: bool = False
    allow_missing_textures: bool = False
    max_error: float | None = None
    """HDR FLIP budget (None: train ``cfg.decoder``)."""
    warnings: list[str] = field(default_factory=list)
    """Planning warnings (a capped grid): recorded in the summary's ``warnings`` and ``notes``."""
    latent: dict | None = None
    """The plan's grid decision (:meth:`mtlx2neural.pipeline.plan.MaterialPlan.latent_info`): the summary's ``latent``."""
    threads: int | None = None
    """torch threads in the worker (None: leave torch's default)."""
    ship: bool = False
    """Train in a temporary folder and return its files with the summary (a remote worker)."""
    checkpoint: bytes | None = None
    """With ``ship`` and ``resume``: the checkpoint to resume from."""
    progress_queue: object = None
    """A pool worker sends (index, step, total, loss, phase) here for the parent's progress bars."""
    index: int = 0
    options: dict | None = None
    """The conversion's options (:func:`mtlx2neural.pipeline.options.options_record`): the summary's ``options``."""
    input_hash: str | None = None
    """:func:`~mtlx2neural.pipeline.source_hash.input_hash` of the material: the summary's ``input_hash``."""
    stage_file: str | None = None
    """The USD stage whose bound meshes provide the geometry the graph reads (``MaterialSource.stage_file``)."""
    application: Application | None = None
    """The instant ``time``/``frame`` nodes fold to (``--frame``/``--fps``; None: frame 1 at 24 fps)."""

    def source(self):
        """The :class:`~mtlx2neural.scene.MaterialSource` rebuilt from the XML."""
        import MaterialX as mx


        doc = mx.createDocument()
        mx.readFromXmlString(doc, self.document_xml)
        return MaterialSource(self.name, doc, self.material, self.source_file, list(self.bound_prims),
                              stage_file=self.stage_file)


def make_job(plan, folder: Path, cfg: TrainConfig, **options) -> MaterialJob:
    """The job for a :class:`mtlx2neural.pipeline.plan.MaterialPlan` (``options``: the other fields)."""
    import MaterialX as mx

    src = plan.source
    return MaterialJob(src.name, src.material, src.source_file, list(src.bound_prims),
                       mx.writeToXmlString(src.document), str(folder), cfg, plan.digest, plan.content,
                       tuple(plan.grid), warnings=list(plan.warnings), latent=plan.latent_info(),
                       stage_file=getattr(src, "stage_file", None), input_hash=input_hash(src), **options)


def run_job(job: MaterialJob) -> dict:
    """Train one material (any runner calls this); returns its summary (also in ``summary.json``).

    With ``job.ship`` the summary carries ``_files`` ({name: bytes} of the folder's files).
    """
    global _LISTENER
    if job.threads:
        torch.set_num_threads(job.threads)
    if job.progress_queue is not None:
        q, i = job.progress_queue, job.index
        _LISTENER = lambda step, total, rec: q.put((i, step, total, rec["loss_brdf"], rec["phase"]))  # noqa: E731
    fault_point("job", job.name)  # tests: a worker that dies abruptly (mtlx2neural.faults)
    src = job.source()
    device = resolve_device(job.device)
    folder = Path(tempfile.mkdtemp(prefix="mtlx2neural_")) if job.ship else Path(job.folder)
    folder.mkdir(parents=True, exist_ok=True)
    if job.ship and job.checkpoint is not None:
        (folder / "checkpoint.pt").write_bytes(job.checkpoint)
    extra = {"content_hash": job.content, "warnings": list(job.warnings), "notes": list(job.warnings)}
    if job.input_hash is not None:
        extra["input_hash"] = job.input_hash
    if job.latent is not None:
        extra["latent"] = job.latent
    if job.options is not None:
        extra["options"] = job.options
    try:
        with _running():
            if job.max_error is None:
                _, summary = train_material(src, job.cfg, folder, device, job.resume, job.progress,
                                            job.allow_missing_textures, job.digest, job.resolution, extra,
                                            application=job.application)
            else:
                summary = train_within_budget(src, job.cfg, folder, device, job.resume, job.progress,
                                              job.allow_missing_textures, job.digest, job.max_error,
                                              job.resolution, extra, application=job.application)
        if job.ship:
            summary = {**summary, "_files": {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}}
        return summary
    finally:
        if job.ship:
            shutil.rmtree(folder, ignore_errors=True)


# ----------------------------------------------------------------------------- runners

_LISTENER = None  # a pool worker's progress callback for Trainer.run (set by run_job)
_RUNNING = False  # a pool worker: is a job running (Ctrl-C interrupts it) or is it idle (Ctrl-C ignored)?
_INTERRUPTED = False  # has the running job been interrupted already?


@contextmanager
def _running():
    global _RUNNING, _INTERRUPTED
    _RUNNING, _INTERRUPTED = True, False
    try:
        yield
    finally:
        _RUNNING = False


def _pool_sigint(signum, frame):
    global _INTERRUPTED
    if _RUNNING and not _INTERRUPTED:  # the trainer saves a checkpoint and raises TrainingInterrupted;
        _INTERRUPTED = True  # a second signal (the terminal's, then the parent's) must not cut that save short
        raise KeyboardInterrupt


def init_pool_worker(threads: int) -> None:
    """A spawned pool worker's initializer: Ctrl-C (SIGINT) or SIGTERM interrupts a running job only, which
    saves its checkpoint; ``threads`` torch threads."""
    import signal

    signal.signal(signal.SIGINT, _pool_sigint)
    signal.signal(signal.SIGTERM, _pool_sigint)
    torch.set_num_threads(threads)
