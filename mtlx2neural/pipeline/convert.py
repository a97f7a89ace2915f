"""``mtlx2neural ASSET``: train a neural material for every material the scene selects, then export.

Steps (the library behind the default command):

0. check every setting and the device (:func:`mtlx2neural.pipeline.options.check_options`,
   :func:`mtlx2neural.pipeline.devices.check_device`), then, once the materials are selected, every
   path the run will write (:mod:`.layout`): nothing is trained for a run that
   could not finish or would overwrite the input;
1. select: the materials renderable geometry binds (:func:`mtlx2neural.scene.load_asset`;
   the others are reported as skipped, with the reason), or only ``material``;
2. plan (:mod:`.plan`): compile each, decide its latent grid (1x1 when uniform; the
   textures' grid, scaled down to what the bound meshes' UVs need at ``texel_density``
   texels per metre and capped at ``cfg.max_resolution`` texels per side, with a warning
   when that loses detail), the settings it trains with, its source hash, and which
   materials are identical (same name-free content hash, grid included): those train
   once and share the first one's result;
   a selected material that cannot be read or compiled (an :class:`InputError`: unsupported
   node, bad value, missing texture) is left out with its node and reason
   (``Summaries.failed``, the layer's ``skippedMaterials``) and keeps its original network;
   the others convert. None convertible, or ``strict``: the error, before anything is written;
   a material whose training raises (a non-finite loss, out of memory, an error in a worker
   process or a Ray task: step 4) is skipped the same way once the others have trained
   (``Summaries.failed``, with reason ``training failed (<error type>): ...``); none trained,
   or ``strict``: the error and no layer (a fresh output folder is removed). Ctrl-C stops all;
3. reuse: a material whose ``summary.json`` carries the same source hash (document,
   texture bytes, settings: :mod:`.source_hash`) is not trained again (``force``
   retrains);
4. train the rest as jobs (:mod:`.jobs`): in this process, a local process pool
   (``workers``) or Ray; with ``max_error`` each job picks the smallest decoder whose
   HDR FLIP meets the budget. Each writes into ``OUT/<material>/``: ``checkpoint.pt``,
   ``training_curves.csv``, ``summary.json`` (the material's
   :class:`~mtlx2neural.material_record.MaterialRecord`: settings, hashes, time, held-out error,
   HDR FLIP at three views, notes) and PNG renders of reference, neural model and FLIP
   map per view. A shared material's folder gets a ``summary.json`` with
   ``shared_with`` and a link (or copy) of the checkpoint;
5. export (:mod:`.export.bundle`): latent EXRs and FP16 weights into
   ``OUT/<material>/neural/`` (a shared material gets its own copy) and the neural USD
   layer ``OUT.parent/<OUT name>.usda``.

``OUT`` defaults to ``<asset folder>/<asset stem>_neural`` (``-o`` may also name the
layer: ``OUT.usda``); the input is never modified. One run at a time holds ``OUT``
(:mod:`.lock`). A ``--material`` run updates that material in an existing layer
and keeps the others (the layer's record lists them, with their source hashes).

The asset may also be an open ``Usd.Stage`` (:func:`convert_asset`; the library entry
point is :func:`mtlx2neural.convert`): it is read as composed, and one with unsaved or
in-memory edits is converted from a flattened snapshot written into ``OUT``.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import warnings
from pathlib import Path

from mtlx2neural.baseline.analytic_model import BASELINE_FILE
from mtlx2neural.errors import InputError
from mtlx2neural.export import export_asset
from mtlx2neural.export.bundle import EXPORT_FOLDER
from mtlx2neural.export.usd_writer import KeptMaterials, register_schema
from mtlx2neural.material_record import (
    MaterialRecord,
    read_record_or_none,
    write_record,
)
from mtlx2neural.model.checkpoint import (
    checkpoint_file,
    load_checkpoint,
    read_checkpoint,
    resume_conflicts,
)
from mtlx2neural.pipeline.budget import BUDGET_FOLDER
from mtlx2neural.pipeline.devices import check_device
from mtlx2neural.pipeline.jobs import make_job
from mtlx2neural.pipeline.layout import (  # noqa: F401 (API)
    SNAPSHOT_NAME,
    WORK_FOLDER,
    OutputLayout,
    check_output,
    default_output,
    material_folder,
    material_folders,
    prepare_folder,
    prepare_work_folder,
    resolve_output,
    work_folder,
)
from mtlx2neural.pipeline.lock import output_lock
from mtlx2neural.pipeline.options import (
    ConvertOptions,
    application_of,
    check_options,
    options_record,
)
from mtlx2neural.pipeline.plan import (  # noqa: F401 (latent_resolution: API)
    DECODERS,
    MaterialFailure,
    latent_resolution,
    plan_materials,
)
from mtlx2neural.pipeline.quality import judge, verdict
from mtlx2neural.pipeline.scene_network import (
    apply_scene_digests,
    poorly_fitted,
    run_scene_jobs,
    trained_network,
)
from mtlx2neural.pipeline.source_hash import cached_record, input_hash
from mtlx2neural.pipeline.workers import check_workers, run_jobs
from mtlx2neural.scene import find_material, load_asset
from mtlx2neural.scene.dependencies import input_files
from mtlx2neural.scene.snapshot import flatten, unsaved_layers, write_snapshot
from mtlx2neural.scene.usd_stage import is_stage, stage_name
from mtlx2neural.staging import recover as recover_staging
from mtlx2neural.train.config import PRESETS, TrainConfig
from mtlx2neural.version import __version__


def preset_name(cfg: TrainConfig) -> str:
    """The preset ``cfg`` equals, else "custom"."""
    return next((name for name, p in PRESETS.items() if p == cfg), "custom")


def _select(scene, asset, material):
    sources = [s for s in scene.materials
               if material is None or material in (s.name, s.name.rsplit("/", 1)[-1], s.material)]
    if not sources and material is not None:

        sources = [find_material(asset, material)]  # an explicitly named material, even if unbound
    if not sources:
        choices = [s.name for s in scene.materials] + [f"{n} (skipped: {why})" for n, why in scene.skipped]
        what = f"no material named '{material}'" if material else "no material bound to renderable geometry"
        raise InputError(f"{scene.asset}: {what}. Materials: {', '.join(choices) or 'none'}. "
                         f"Name one with --material.")
    return sources


def _nothing_convertible(asset, failures) -> InputError:
    """The error of a run none of whose selected materials can be converted (exit 2)."""
    listing = "\n".join(f"  {f.material}: {f.reason}" for f in failures)
    return InputError(f"{asset}: no material could be converted ({len(failures)} failed):\n{listing}",
                      node=failures[0].node)


def _training_failed(asset, failures) -> InputError:
    """The ``strict`` error of a run some of whose materials failed to train (exit 2, no layer)."""
    listing = "\n".join(f"  {f.material}: {f.reason}" for f in failures)
    return InputError(f"{asset}: --strict: {len(failures)} material(s) failed to train, so no layer was "
                      f"written:\n{listing}", node=failures[0].node)


def _reuse(folder: Path, digest: str):
    """(model, record) of an earlier run of the same source hash in ``folder``, or None."""
    record = cached_record(folder, digest)
    if record is None or record.shared_with:  # a shared folder's checkpoint is another's
        return None
    try:
        model = load_checkpoint(folder)
    except InputError:  # unreadable: train again
        return None
    return (model, record) if model.checkpoint_step == record.steps else None


def _reusable(plan, folder: Path):
    """(``_reuse``'s result or None, the folder it came from): the committed ``folder`` first, then its
    work folder (a result an earlier run trained but could not export, e.g. on a full disk)."""
    reused = _reuse(folder, plan.digest)
    if reused is None and (reused := _reuse(work_folder(folder), plan.digest)) is not None:
        return reused, work_folder(folder)
    return reused, folder


class Summaries(list):
    """The per-material records (:class:`~mtlx2neural.material_record.MaterialRecord`) of
    :func:`convert_asset`, plus ``skipped``: the scene's materials
    left out (``{"material", "reason"}``; only when no ``material`` was named), ``failed``: the
    selected materials that could not be converted (or whose training failed) and were skipped (``{"material", "node",
    "reason"}``, :class:`~mtlx2neural.pipeline.plan.MaterialFailure`; the CLI then exits 3),
    ``kept``: the materials an existing layer kept from earlier runs (a ``--material`` run),
    ``folder``: the output folder, and ``layer``: the neural layer written."""

    skipped: list[dict]
    failed: list[dict]
    kept: list[str]
    folder: Path
    layer: Path


def _share(src, plan, rep: MaterialRecord, rep_folder: Path, folder: Path) -> MaterialRecord:
    """The record of ``src``, which reuses the result of ``plan.shared_with`` (trained in ``rep_folder``)."""
    folder.mkdir(parents=True, exist_ok=True)
    record = dataclasses.replace(rep, material=src.name, mtlx_material=src.material, source=src.source_file,
                                 bound_prims=list(src.bound_prims), source_hash=plan.digest,
                                 shared_with=plan.shared_with, latent=plan.latent_info(),
                                 input_hash=input_hash(src), cached=False)
    # the checkpoint, so that `render --material` finds it; the analytic baseline, for the export's preview
    for name in ("checkpoint.pt", BASELINE_FILE):
        target = folder / name
        target.unlink(missing_ok=True)
        if not (rep_folder / name).exists():
            continue
        try:
            os.link(rep_folder / name, target)
        except OSError:
            shutil.copyfile(rep_folder / name, target)
    write_record(folder, record)
    return record


def _check_resume(plans, folders, max_error) -> None:
    """Before training: every checkpoint a ``--resume`` run would continue (an interrupted run's, in the
    work folder, else the final folder's) is readable and was trained with the same network shape
    (else :class:`InputError` naming it and the difference)."""
    for plan, folder in zip(plans, folders):
        if plan.shared_with:
            continue
        work = work_folder(folder)
        folder = work if checkpoint_file(work).is_file() or (work / BUDGET_FOLDER).is_dir() else folder
        sizes = [folder / BUDGET_FOLDER / d for d in DECODERS] if max_error is not None else [folder]
        for place in sizes:
            f = checkpoint_file(place)
            if not f.is_file():
                continue
            remedy = "delete it to start that material afresh, or run without --resume"
            ck = read_checkpoint(f, "cpu", remedy)
            settings = dataclasses.asdict(plan.cfg)
            if max_error is not None:
                settings["decoder"] = place.name
            diff = resume_conflicts(ck, settings, tuple(plan.grid))
            if diff:
                raise InputError(f"{f}: --resume cannot continue this checkpoint, whose network differs from "
                                 f"this run's ({'; '.join(diff)}). Rerun with the checkpoint's settings, or "
                                 f"without --resume (--force retrains from scratch)")


def _kept_materials(layout: OutputLayout, record, names, material, found=()) -> KeptMaterials | None:
    """With ``--material``, the previous layer's other materials whose files are still there. A kept
    material whose input changed since it was trained (its record's ``input_hash`` differs from that of
    ``found``'s material of that name) is kept, with a warning naming it and the fix."""
    if record is None or material is None:
        return None
    current = {s.name: s for s in found}
    entries = {}
    for name, entry in record.materials.items():
        if name in names:
            continue
        folder = (layout.layer.parent / entry.get("folder", "")).resolve()
        if entry.get("folder") and (folder / EXPORT_FOLDER / "weights.json").is_file():
            entries[name] = entry
            if _stale(folder, current.get(name)):
                warnings.warn(f"{layout.layer}: keeping {name} as it was converted, but its input has changed "
                              f"since (its graph or textures); its neural model is stale. Convert it again "
                              f"(--material {name} --force, or the whole asset with --force)", stacklevel=3)
        else:
            warnings.warn(f"{layout.layer}: dropping {name} from the layer: its exported files are gone "
                          f"({folder / EXPORT_FOLDER})", stacklevel=3)
    return KeptMaterials(layout.layer, entries)


def _stale(folder: Path, source) -> bool:
    """Does the material ``source`` differ from the input its record in ``folder`` was trained on?
    (False when unknown: no source, or no readable record.)"""
    record = read_record_or_none(folder)
    recorded = record.input_hash if record is not None else None
    return bool(recorded and source is not None and recorded != input_hash(source))


def convert_asset(asset, options: ConvertOptions | None = None) -> Summaries:
    """Train (or reuse, or share) every selected material (or only ``options.material``), then export them.

    ``asset``: a ``.mtlx`` or USD file, or an open ``Usd.Stage`` (below). ``options``
    (:class:`~mtlx2neural.pipeline.options.ConvertOptions`, checked first by ``check_options``;
    None: the defaults) holds every setting; its field docstrings document them. ``out``:
    the output folder, or the layer's path when it ends in ``.usda``/``.usd``/``.usdc``
    (:func:`mtlx2neural.pipeline.layout.resolve_output`; default ``<asset stem>_neural``
    beside the file); ``usda`` overrides the layer's path. Every setting, device and output
    path is checked before any training (:class:`InputError` otherwise): the outputs never
    touch the input or the files it reads, nor files this tool did not write
    (:mod:`.layout`); one run at a time holds the output folder (:mod:`.lock`). With
    ``material``, an existing layer keeps its other materials.

    A ``Usd.Stage`` is read as composed, session-layer and unsaved edits included
    (:func:`mtlx2neural.scene.load_asset`). When its root layer is a file and nothing is
    unsaved, the run is exactly that of the file. Otherwise (an in-memory root layer, a
    non-empty session or anonymous layer, a dirty file layer) the composed stage is
    flattened into ``OUT/stage-snapshot.usda`` (:mod:`mtlx2neural.scene.snapshot`, written
    atomically just before the export), which the neural layer sublayers and the summaries
    name as ``source``, so ``report`` and ``render`` can load the reference later; a file
    stage with unsaved edits warns that the snapshot, not the file, is converted. A later
    conversion from a file into the same folder deletes that snapshot, now stale (unless it
    keeps other materials of the earlier layer, whose summaries may name it). An
    in-memory root layer has no folder, so ``out`` (or ``usda``) is then required. The
    stage is never changed and nothing is written outside the output folder and the layer.

    Returns one :class:`~mtlx2neural.material_record.MaterialRecord` per material, its ``latent``
    (the plan's grid decision), ``cached`` (True: reused, nothing trained), ``shared_with`` (the
    material whose result it shares, else None), ``usd`` (the layer written) and ``export_notes``
    (FP16 range-check notes) filled in; the list also carries ``skipped``,
    ``failed`` (materials that could not be converted, when others could; ``options.strict``
    raises instead), ``kept``, ``folder`` and ``layer`` (:class:`Summaries`). ``neural:metrics:preset``
    records ``options.preset`` (or the preset ``options.train`` equals).
    """
    if options is not None and not isinstance(options, ConvertOptions):
        raise TypeError(f"convert_asset(asset, options): options is a ConvertOptions "
                        f"(mtlx2neural.pipeline.options), not {type(options).__name__}")
    return _convert(asset, ConvertOptions() if options is None else options)


def _stage_layout(stage, options: ConvertOptions) -> OutputLayout:
    """The layout for an open stage: beside its root layer's file, or ``out`` (required in memory)."""
    root = stage.GetRootLayer()
    if root.anonymous and not (options.out or options.usda):
        raise InputError(f"{stage_name(stage)}: the stage's root layer is in memory (anonymous), so there is "
                         f"no folder to write beside; give an output folder (ConvertOptions.out, or -o)")
    return resolve_output(root.realPath if root.realPath else None, options.out or options.usda)


def _convert(asset, options: ConvertOptions) -> Summaries:
    # 1. options, before reading anything
    cfg = check_options(options)
    named = preset_name(cfg) if options.train is not None else "custom"
    label = named if named != "custom" else options.preset  # the preset options.train equals, else options.preset
    device = check_device(options.device)
    workers = check_workers(options.workers)
    material = options.material
    register_schema()  # before USD's schema registry is first built
    stage = asset if is_stage(asset) else None
    layout = _stage_layout(stage, options) if stage is not None else None  # an in-memory stage needs out
    # 2. the scene and the materials to convert
    scene = load_asset(asset, keep_going=not options.strict)
    # a named material that fails is reloaded by _select, which raises its error
    failures = [MaterialFailure.of(n, e) for n, e in scene.failed] if material is None else []
    if failures and not scene.materials:
        raise _nothing_convertible(scene.asset, failures)
    sources = _select(scene, asset, material)
    # 3. where everything goes, checked against the files the input reads (nothing written yet)
    layout = layout or resolve_output(asset, options.out)
    if options.usda:
        layout = OutputLayout(layout.folder, Path(os.path.abspath(options.usda)))
    names = material_folders([s.name for s in sources])
    folders = [layout.folder / names[s.name] for s in sources]
    read = list({id(s): s for s in [*scene.materials, *sources]}.values())  # a named material may be both
    inputs = input_files(asset, read)
    source, flat = _stage_source(stage, layout) if stage is not None else (scene.asset, None)
    if flat is not None:  # the materials' networks are reloaded from the snapshot (report, render)
        sources = [dataclasses.replace(s, source_file=str(source)) if s.network else s for s in sources]
    for root in {layout.layer.parent, layout.folder}:  # a commit a crash interrupted: settled before reading
        recover_staging(root)
    record = check_output(layout, source, inputs, folders)
    # 4. plans (compiling every graph surfaces bad documents) and --resume compatibility
    plans = plan_materials(sources, cfg, options.allow_missing_textures, options.max_error,
                           options.texel_density, stage if stage is not None else scene.asset,
                           failures=None if options.strict else failures, strict=options.strict,
                           application=application_of(options), encoder=options.encoder,
                           universal_steps=options.universal_steps, universal_tune=options.universal_tune)
    if failures:  # the others convert; a failed material keeps its original network only
        if not plans:
            raise _nothing_convertible(scene.asset, failures)
        index = {id(s): i for i, s in enumerate(sources)}
        kept = [index[id(p.source)] for p in plans]
        sources, folders = [sources[i] for i in kept], [folders[i] for i in kept]
    for p in plans:
        p.compiled = None  # the workers compile again (on their device); keep the parent small
    if options.network == "scene":
        apply_scene_digests(plans)
    if options.resume:
        _check_resume(plans, folders, options.max_error)
    keep = _kept_materials(layout, record, {s.name for s in sources}, material, scene.materials)
    # 5. the output folder: writable, ours, and held by this run alone
    fresh = not layout.folder.exists()  # removed again when training leaves nothing to export
    prepare_folder(layout, source, __version__)
    error = None
    try:
        with output_lock(layout.folder):
            summaries, trained = _train_and_share(plans, folders, cfg, device, options.resume, options.progress,
                                                  options.allow_missing_textures, options.force, workers,
                                                  options.max_error, options_record(options),
                                                  application_of(options), options.network)
            trained = _quality_gate(summaries, trained, options.flagged)
            if summaries.failed and (options.strict or not trained):  # all or nothing: no layer
                error = (_training_failed(scene.asset, summaries.failed) if options.strict
                         else _nothing_convertible(scene.asset, failures + summaries.failed))
                raise error
            failures = failures + summaries.failed
            layer, exported = _export(summaries, trained, scene, material, cfg, flat, source, layout, label,
                                      keep, failures, options)
            shutil.rmtree(layout.folder / WORK_FOLDER, ignore_errors=True)  # committed: the work is in place
    except InputError as exc:
        if exc is error and fresh:  # a folder this run created, for nothing
            shutil.rmtree(layout.folder, ignore_errors=True)
        raise
    for s, e in zip(summaries, exported):
        s.usd, s.export_notes = str(layer), e.notes
    summaries.kept = sorted(keep.entries) if keep else []
    summaries.failed = [f.record() for f in failures]
    summaries.folder, summaries.layer = layout.folder, Path(layer)
    return summaries


def _quality_gate(summaries, trained: list[tuple], policy: str) -> list[tuple]:
    """Judge every trained material (:mod:`.quality`), record the verdict in its record (and its
    ``summary.json``), warn about each flagged one, and apply ``policy``: ``skip`` moves it to
    ``summaries.failed``. Returns the materials to export; ``summaries`` is updated in place."""
    flagged = judge(summaries)
    effect = {"original": "the layer selects its original variant (--flagged neural keeps the neural one)",
              "neural": "the layer selects its neural variant anyway (--flagged neural)",
              "skip": "not exported (--flagged skip)"}[policy]
    kept, records = [], []
    for model, record, folder, fresh in trained:
        reasons = flagged.get(record.material, [])
        record = dataclasses.replace(record, quality=verdict(reasons, policy))
        if reasons:
            record = record.with_warning(f"quality gate: {'; '.join(reasons)}: {effect}")
        write_record(fresh or folder, record)
        if reasons and policy == "skip":
            summaries.failed.append(MaterialFailure(record.material, None,
                                                    f"flagged by the quality gate: {'; '.join(reasons)}"))
            continue
        kept.append((model, record, folder, fresh))
        records.append(record)
    summaries[:] = records
    return kept


def _export(summaries, trained, scene, material, cfg, flat, source, layout, label, keep, failures, options):
    """Write the neural layer and the export of ``trained`` (under the output lock): (layer, exported)."""
    summaries.skipped = [{"material": n, "reason": r} for n, r in scene.skipped] if material is None else []
    if cfg.iterations == 0:
        for s in summaries:
            s.warnings = [*s.warnings, "exported untrained (--iterations 0 --allow-untrained)"]
    if flat is not None:
        write_snapshot(flat, source)
    group = layout.folder.name if options.network == "scene" else None  # the shared module's name
    layer, exported = export_asset(source, trained, layout.folder, label, layout.layer, keep=keep,
                                   tool_version=__version__, skipped={f.material: f.reason for f in failures},
                                   engine_shaders=options.engine_shaders, shared_network=group)
    if flat is None and not (keep and keep.entries):
        # An earlier conversion's snapshot of an in-memory or edited stage: the new layer sublayers
        # the file instead, so it is stale (kept materials' summaries may still name it: kept then).
        (layout.folder / SNAPSHOT_NAME).unlink(missing_ok=True)
    return layer, exported


def _stage_source(stage, layout: OutputLayout):
    """(the input as a file, the flattened layer to write there or None) for an open ``stage``: its
    root layer's file when nothing is unsaved, else ``OUT/stage-snapshot.usda`` (with a warning
    for a file stage, whose file is then not what is converted)."""
    root = stage.GetRootLayer()
    unsaved = unsaved_layers(stage)
    if not root.anonymous and not unsaved:
        return root.realPath, None
    target = layout.folder / SNAPSHOT_NAME
    if not root.anonymous:
        warnings.warn(f"{root.realPath}: the stage has unsaved edits (in {', '.join(unsaved)}); converting a "
                      f"snapshot of the composed stage, {target}, which the neural layer sublayers instead of "
                      f"the file. Save the stage first to convert the file itself", stacklevel=4)
    return target, flatten(stage)


def training_failure(material: str, exc: BaseException) -> MaterialFailure:
    """The :class:`MaterialFailure` of a material whose training raised ``exc`` (a non-finite loss,
    out of memory, an error in a worker process or Ray task)."""
    what = "out of memory" if isinstance(exc, MemoryError) or "out of memory" in str(exc).lower() else None
    reason = f"training failed ({what or type(exc).__name__}): {exc}"
    return MaterialFailure(material, getattr(exc, "node", None), reason)


def _train_and_share(plans, folders, cfg, device, resume, progress, allow_missing_textures, force, workers,
                     max_error, options: dict | None = None, application=None,
                     network: str = "material") -> tuple[Summaries, list[tuple]]:
    """Reuse, train (as jobs) or share each plan's material: (summaries, (model, record, folder, fresh)
    per converted plan; ``fresh``: the work folder holding its new training files, None when reused).
    ``options``: the conversion's options record (:func:`options_record`). A plan whose training raised (and one sharing its result) is left out and listed
    in ``summaries.failed`` (:class:`MaterialFailure`); the others train to the end.
    ``network="scene"``: the jobs train together with one shared network
    (:mod:`~mtlx2neural.pipeline.scene_network`), or, when the reused materials' network can be kept
    (:func:`~mtlx2neural.pipeline.scene_network.trained_network`), each fits its latents into it; when one of
    those would then fail the quality gate (:func:`~.scene_network.poorly_fitted`), the whole
    group trains again (as with ``force``), and that material's record says why."""
    # Reused: a committed result, else one an earlier run trained but could not export (a full disk).
    found = {} if force else {i: _reusable(p, f) for i, (p, f) in enumerate(zip(plans, folders))
                              if not p.shared_with}
    kept_network = None  # scene mode: the earlier run's network the materials to train are fitted into
    if network == "scene" and any(reused is None for reused, _ in found.values()):
        kept_network = trained_network([hit for hit in found.values() if hit[0] is not None],
                                       [plans[i].cfg for i, (r, _) in found.items() if r is None])
        if kept_network is None:
            found = {}  # nothing to keep: the shared network is trained again for all
    results: dict[int, tuple] = {}  # plan index -> (model or None, record, cached)
    uncommitted: dict[int, Path] = {}  # plan index -> the work folder of a reused result not yet committed
    jobs, job_plans = [], []
    for i, (plan, folder) in enumerate(zip(plans, folders)):
        if plan.shared_with:
            continue
        reused, where = found.get(i, (None, folder))
        if reused is not None:
            model, record = reused
            if record.source != plan.source.source_file:  # e.g. a stage snapshot, now the saved file
                record = dataclasses.replace(record, source=plan.source.source_file)
                write_record(where, record)
            results[i] = (model, record, True)
            if where != folder:
                uncommitted[i] = where
            if progress:
                print(f"{plan.name}: unchanged since the last run (source hash {plan.digest[:12]}): "
                      f"reusing {folder}", flush=True)
            continue
        jobs.append(make_job(plan, prepare_work_folder(folder, resume), plan.cfg, device=device, resume=resume,
                             progress=progress,
                             allow_missing_textures=allow_missing_textures, max_error=max_error,
                             options=options, application=application))
        job_plans.append(i)

    finished = []

    def report(k: int, s: MaterialRecord) -> None:  # one line per finished material, in the parent
        finished.append(k)
        if progress and len(jobs) > 1:
            print(f"[{len(finished)}/{len(jobs)}] {s.material}: decoder {s.decoder}, {s.steps} steps "
                  f"in {s.seconds} s, HDR FLIP {s.flip_mean:.4f}", flush=True)

    errors: dict[int, MaterialFailure] = {}  # plan index -> why its training failed

    def failed(k: int, exc: BaseException) -> None:
        i = job_plans[k]
        errors[i] = training_failure(plans[i].name, exc)
        if progress:
            print(f"{plans[i].name}: {errors[i].reason}", flush=True)

    ran = (run_scene_jobs(jobs, report, failed, kept_network, workers) if network == "scene"
           else run_jobs(jobs, workers, report, failed))
    poor = poorly_fitted(ran, [r for _, r, cached in results.values() if cached]) if kept_network else {}
    if poor:  # the kept network cannot model an added material: the group trains again, with it
        why = "; ".join(f"{name}: {', '.join(reasons)}" for name, reasons in poor.items())
        if progress:
            print(f"--network scene: fitted into the kept network, {why}; training the whole group again", flush=True)
        summaries, trained = _train_and_share(plans, folders, cfg, device, resume, progress, allow_missing_textures,
                                              True, workers, max_error, options, application, network)
        for _, record, _, _ in trained:
            if record.material in poor:
                record.notes.append(f"fitted into the scene's kept network it would fail the quality gate "
                                    f"({', '.join(poor[record.material])}), so the whole group was trained again")
        return summaries, trained
    for k, s in enumerate(ran):
        i = job_plans[k]
        if s is not None:
            results[i] = (load_checkpoint(jobs[k].folder), s, False)
    first = {p.name: i for i, p in reversed(list(enumerate(plans)))}
    summaries, trained = Summaries(), []
    summaries.failed = []
    for i, (plan, folder) in enumerate(zip(plans, folders)):
        if i in errors:
            summaries.failed.append(errors[i])
            continue
        if plan.shared_with:
            j = first[plan.shared_with]
            if j in errors:  # shares the result of a material whose training failed
                summaries.failed.append(MaterialFailure(plan.name, None, f"identical to {plan.shared_with}, "
                                                        f"whose training failed: {errors[j].reason}"))
                continue
            model, rep, cached = results[j]
            rep_files = work_folder(folders[j]) if (not cached or j in uncommitted) else folders[j]
            fresh = prepare_work_folder(folder, False)
            record = _share(plan.source, plan, rep, rep_files, fresh)
            if progress:
                print(f"{plan.name}: identical to {plan.shared_with} (same compiled graph, textures and "
                      f"settings; content hash {plan.content[:12]}): trained once, sharing its result", flush=True)
        else:
            model, record, cached = results[i]
            fresh = work_folder(folder) if (not cached or i in uncommitted) else None
        record = dataclasses.replace(record, cached=cached, latent=plan.latent_info())
        trained.append((model, record, folder, fresh))
        summaries.append(record)
    return summaries, trained
