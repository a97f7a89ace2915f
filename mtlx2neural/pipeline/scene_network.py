"""``--network scene``: every material a conversion trains shares one decoder and one sampler.

The jobs of :func:`~mtlx2neural.pipeline.convert.convert_asset` (one per material to train) are run in
this process instead of one worker per material: each material is prepared as a per-material run
prepares it (:func:`~mtlx2neural.pipeline.material_training.prepare_material`: its reference, training
stack, surface maps, trainer), the trainers are trained together
(:class:`~mtlx2neural.train.shared.SharedTrainer`), and each material is then measured and recorded from
its checkpoint in the worker pool, as a per-material run records it
(:func:`~mtlx2neural.pipeline.material_training.finish_from_checkpoint`), its record's ``network`` naming
the group. On a CPU with two cores or more (and ``--workers`` other than 1), a second process draws the
joint steps' training rows from the references while this one trains the networks
(:mod:`~mtlx2neural.train.row_process`, :func:`row_process`).

Reuse: each material's source hash is marked as a scene-mode hash (:func:`apply_scene_digests`), so a
per-material result is never reused as part of a shared network (or the other way round). The network's
``id`` (its record's ``network``) names the joint training that made it. When some materials of the run
are unchanged since that training (their hash matches, :func:`trained_network`) and the others are new
or changed, the network is kept: each of the others fits its encoder and latents alone against it, frozen
(:func:`~mtlx2neural.train.shared.fit_into_network`), and the weights that ship do not change. A network
trained without a material may not model it (on the scene sample, a leaf added to a network of lava and
gold reaches HDR FLIP 0.35, against 0.07 trained with them, and twice the steps do not help): when an
added material would fail the quality gate, the conversion trains the whole group again. So does a run
with nothing reusable, or with results of two different trainings, and ``--force``.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import math
import statistics
import time
from pathlib import Path

import torch

from mtlx2neural.errors import InputError
from mtlx2neural.material_record import write_record
from mtlx2neural.model.checkpoint import checkpoint_file, read_checkpoint
from mtlx2neural.pipeline.devices import resolve_device
from mtlx2neural.pipeline.material_training import (
    apply_energy,
    prepare_material,
    row_trainer,
)
from mtlx2neural.pipeline.quality import flag_reasons
from mtlx2neural.pipeline.workers import (
    WarmPool,
    available_cpus,
    default_workers,
    parse_workers,
    run_jobs,
)
from mtlx2neural.train.row_process import RowProcess
from mtlx2neural.train.shared import (
    ADDED_FRACTION,
    SharedTrainer,
    fit_into_network,
    latent_steps,
    scene_batch,
    shape_differences,
)
from mtlx2neural.train.trainer import TrainingInterrupted
from mtlx2neural.universal.choice import SCENE_FINE_TUNE_ROWS, SCENE_STEP_SHARE
from mtlx2neural.universal.fit import (
    LayoutMismatch,
    load_encoder,
    load_networks,
    use_fine_tune_schedule,
)
from mtlx2neural.universal.weights import load_weights


def apply_scene_digests(plans) -> None:
    """Mark each plan's ``digest`` (its source hash) as a scene-mode hash (module docstring)."""
    for p in plans:
        p.digest = hashlib.sha256(f"{p.digest}\0network=scene".encode()).hexdigest()


@dataclasses.dataclass
class TrainedNetwork:
    """The shared network of an earlier ``--network scene`` run, kept for the materials added to it."""

    model: object
    """A :class:`~mtlx2neural.model.neural_material.NeuralMaterial` of the group (its decoder and sampler)."""
    info: dict
    """The group's record (a :class:`~mtlx2neural.material_record.MaterialRecord`'s ``network``)."""
    environment_history: list
    """The group's environment-head fit, as its checkpoints record it."""


def trained_network(reused: list[tuple], configs: list) -> TrainedNetwork | None:
    """The network that every reused result of a scene-mode run (``reused``: ((model, record), the folder
    of its checkpoint) pairs) shares, if the materials still to train (``configs``: their ``TrainConfig``)
    can be fitted into it; None when there is nothing reused, when the reused results come from
    different trainings (or predate the network's ``id``), or when a config differs from the group's in
    the network's shape or schedule."""
    if not reused:
        return None
    ids = {(r.network or {}).get("id") for (_, r), _ in reused}
    if len(ids) != 1 or None in ids:
        return None
    (model, record), folder = reused[0]
    if any(shape_differences(c, record.config) for c in configs):
        return None
    try:
        history = read_checkpoint(checkpoint_file(folder)).get("environment_history") or []
    except InputError:
        return None
    info = {k: v for k, v in record.network.items() if k != "added"}
    return TrainedNetwork(model, info, list(history))


def poorly_fitted(added: list, kept: list) -> dict[str, list[str]]:
    """``{material: reasons}`` for the records of ``added`` (materials fitted into a kept network; None
    entries skipped) that the quality gate would flag (:func:`~.quality.flag_reasons`), judged against
    the median HDR FLIP of ``kept`` (the reused materials' records) as the scene's."""
    flips = [r.flip_mean for r in kept if math.isfinite(r.flip_mean)]
    median = statistics.median(flips) if flips else None
    out = {r.material: flag_reasons(r, median) for r in added if r is not None}
    return {name: reasons for name, reasons in out.items() if reasons}


def run_scene_jobs(jobs, report=None, failed=None, network: TrainedNetwork | None = None, workers=None) -> list:
    """Train ``jobs`` (:class:`~mtlx2neural.pipeline.jobs.MaterialJob`) with one shared network; their
    records in job order. A material that cannot be prepared (its graph or textures fail) is passed to
    ``failed(k, exc)`` (None: raised) and left out of the group; a failure of the joint training fails
    every material. ``report(k, record)`` is called as each record is written. ``network``: an earlier
    run's network, kept: each job fits its latents alone against it (:func:`add_to_network`). The joint
    training runs in this process (its rows drawn in a second one: :func:`row_process`); the measures of the
    trained materials (views, energy, preview fit, about 20-40 s per chess material on one core) run in
    ``workers`` processes started with the training (:func:`measure_pool`), two jobs per material (:func:`_measure`)."""
    if not jobs:
        return []
    if network is not None:
        return add_to_network(jobs, network, report, failed, workers)
    device = resolve_device(jobs[0].device)
    progress = jobs[0].progress
    out: list = [None] * len(jobs)
    pool = measure_pool(jobs, device, workers)
    try:
        _train_and_measure(jobs, device, progress, out, report, failed, workers, pool)
    finally:
        if pool is not None:
            pool.close()
    return out


def _train_and_measure(jobs, device, progress, out, report, failed, workers, pool) -> None:
    """:func:`run_scene_jobs`' training and measures, into ``out``."""
    rows = row_process(jobs, device, workers)  # started first: its imports overlap the preparation here
    threads = torch.get_num_threads()
    if rows is not None:  # the row process has a core from now on (more threads than cores: OpenMP collapses)
        torch.set_num_threads(max(1, available_cpus() - 1))
    try:
        setups, kept = [], []
        for k, job in enumerate(jobs):
            cfg = _group_config(job, len(jobs))
            try:
                setups.append(prepare_material(job.source(), cfg, Path(job.folder), device,
                                               job.allow_missing_textures, job.resolution,
                                               application=job.application, canonical=job.encoder is not None))
                kept.append(k)
            except Exception as exc:  # noqa: BLE001 - that material's failure; the group trains without it
                if failed is None:
                    raise
                failed(k, exc)
        if not setups:
            return
        start = warm_start(setups, [jobs[k] for k in kept])
        shared = SharedTrainer([s.trainer for s in setups])
        cfg = shared.cfg
        if rows is not None:
            rows.plan(kept, [s.trainer.cfg for s in setups], shared.requests())
            shared.use_rows(rows)
        if progress:
            print(f"--network scene: {len(setups)} materials share one decoder {cfg.decoder} and one sampler"
                  f"{start.text if start else ''}; {cfg.iterations} joint steps x {cfg.batch} rows per material, "
                  f"then {latent_steps(cfg.iterations)} latent steps per material"
                  f"{'; training rows drawn in a second process' if rows is not None else ''}", flush=True)
        try:
            models = shared.run(progress=progress)
        except KeyboardInterrupt:
            raise TrainingInterrupted(f"interrupted at joint step {shared.step}; --network scene does not resume: "
                                      f"run the conversion again") from None
        except Exception as exc:  # noqa: BLE001 - the shared network failed: so did every material of the group
            if failed is None:
                raise
            for k in kept:
                failed(k, exc)
            return
    finally:
        torch.set_num_threads(threads)
        if rows is not None:
            rows.close()
    group = "\0".join(sorted(jobs[k].digest for k in kept))
    info = {"id": hashlib.sha256(group.encode()).hexdigest()[:16],
            "materials": [jobs[k].name for k in kept], "joint_steps": cfg.iterations,
            "rows_per_material": cfg.batch, "latent_steps": latent_steps(cfg.iterations),
            "seconds": dict(shared.seconds), **({"universal": start.record()} if start else {})}
    del setups, models, shared  # the measures run from the saved checkpoints
    _measure([(k, dataclasses.replace(jobs[k], cfg=_group_config(jobs[k], len(jobs)),
                                      trained=_record_fields(jobs[k], info, start))) for k in kept],
             out, report, failed, workers, pool)


def row_process(jobs, device: str, workers) -> RowProcess | None:
    """A :class:`~mtlx2neural.train.row_process.RowProcess` preparing ``jobs``' trainers as
    :func:`run_scene_jobs` does (:func:`row_trainers`), when one helps: on the CPU, with two cores or more,
    and ``workers`` other than 1 (which asks for everything in this process). None otherwise."""
    if device != "cpu" or available_cpus() < 2 or parse_workers(workers) == 1:
        return None
    return RowProcess(functools.partial(row_trainers, jobs))


def row_trainers(jobs) -> list:
    """Each job's trainer as :func:`run_scene_jobs` prepares it (its group settings; on the CPU, writing
    nothing: :func:`~mtlx2neural.pipeline.material_training.row_trainer`); None where that fails."""
    out = []
    for job in jobs:
        try:
            out.append(row_trainer(job.source(), _group_config(job, len(jobs)), Path(job.folder), "cpu",
                                   job.allow_missing_textures, job.resolution, application=job.application,
                                   canonical=job.encoder is not None))
        except Exception:  # noqa: BLE001 - the parent fails that material itself, and never plans it
            out.append(None)
    return out


def _pool_size(jobs: int, device: str, workers) -> int:
    """The processes of the local pool :func:`~mtlx2neural.pipeline.workers.run_jobs` would run ``jobs`` jobs
    in (0: none, the jobs run in this process or in Ray)."""
    n = parse_workers(workers)
    if isinstance(n, str):
        return 0
    n = min(n or default_workers(jobs, device), jobs)
    return n if n >= 2 else 0


def measure_pool(jobs, device: str, workers) -> WarmPool | None:
    """The measuring processes of ``jobs``' group (:func:`_measure`: two jobs per material), started now,
    as its training starts (:class:`~mtlx2neural.pipeline.workers.WarmPool`); None when the measures will
    not run in a local pool."""
    n = _pool_size(2 * len(jobs), resolve_device(device), workers)
    return WarmPool(n) if n else None


def _measure(trained: list[tuple], out: list, report, failed, workers, pool: WarmPool | None = None) -> None:
    """Measure and record trained materials into ``out``, in ``workers`` processes
    (:func:`~mtlx2neural.pipeline.workers.run_jobs`; each reads its material's checkpoint), passing a failure to
    ``failed``. In a local pool each material is two jobs, its record and its energy check
    (``MaterialJob.part``), joined and written here as both arrive: three materials on two processes then
    leave no process idle for a whole material's measures. ``trained``: (index into ``out``, its job as it was
    prepared for training, with ``trained``: its record fields). ``pool``: the processes to measure in, started
    already (:func:`measure_pool`)."""
    if not trained:
        return
    index = [k for k, _ in trained]
    finishing = [dataclasses.replace(job, resume=False) for _, job in trained]
    if not _pool_size(2 * len(finishing), resolve_device(finishing[0].device), workers):
        records = run_jobs(finishing, workers, report=(lambda i, r: report(index[i], r)) if report else None,
                           failed=(lambda i, exc: failed(index[i], exc)) if failed else None)
        for k, record in zip(index, records):
            out[k] = record
        return
    # a local pool: each material's record and its energy check as two jobs, so the pool's last job is short
    parts = [dataclasses.replace(job, part="record") for job in finishing]
    parts += [dataclasses.replace(job, part="energy") for job in finishing]
    got: dict[int, dict] = {}
    lost: set[int] = set()

    def done(i: int, result) -> None:
        k = index[i % len(index)]
        if k in lost:
            return
        got.setdefault(k, {})[parts[i].part] = result
        if len(got[k]) == 2:  # both parts: the record, checked and written
            record = apply_energy(got[k]["record"], got[k]["energy"])
            write_record(Path(parts[i].folder), record)
            out[k] = record
            if report:
                report(k, record)

    def fail(i: int, exc: BaseException) -> None:
        k = index[i % len(index)]
        if k not in lost:
            lost.add(k)
            failed(k, exc)

    run_jobs(parts, workers, report=done, failed=fail if failed else None, pool=pool)


WARM_SCHEDULE = 0.8
"""A group started from a universal network but holding materials it did not encode runs this share of the
schedule (every phase: the others' encoders, the joint steps, the latent and environment fits). Measured on
the chess set (15 materials at 64², 9 encoded; the neural views' mean HDR FLIP against per-material training's
0.1005): 0.5 gives 0.1138 (+13 %), 0.65 0.1075 (+7.0 %), 0.8 0.1021 (+1.6 %), each share's training phases
costing about its share of the whole schedule's (2026-12-06, docs/history/scene-measures-2026-12-06.md)."""


@dataclasses.dataclass
class WarmStart:
    """A group started from a shipped universal network (:func:`warm_start`)."""

    model: str
    """The shading model whose network the group's decoder and sampler start from."""
    weights_sha: str
    encoded: list[str]
    """The materials whose latents the shipped encoder wrote before the first joint step."""
    others: dict[str, str]
    """The group's other materials: why each trains its own encoder (the full schedule then runs)."""
    steps: int
    """Joint steps: :data:`~mtlx2neural.universal.choice.SCENE_STEP_SHARE` of ``--universal-steps`` when every
    material is encoded, else :data:`WARM_SCHEDULE` of the schedule's."""

    @property
    def text(self) -> str:
        return (f", started from the universal {self.model} network ({len(self.encoded)} of "
                f"{len(self.encoded) + len(self.others)} materials encoded by it)")

    def record(self) -> dict:
        return {"model": self.model, "weights_sha256": self.weights_sha, "encoded": list(self.encoded),
                "own_encoder": dict(self.others), "joint_steps": self.steps}


def warm_start(setups, jobs) -> WarmStart | None:
    """Start a group from a shipped universal network when some of its materials took the universal path
    (``jobs[i].encoder``, ``--encoder universal``; their ``setups[i]`` built on the canonical stack). The
    network of the shading model most of them share (its decoder, environment head and sampler) goes into
    the lead trainer's model, which :class:`~mtlx2neural.train.shared.SharedTrainer` ties every other one
    to; each material of that model bakes its latents with the shipped encoder. When all of the group's
    materials are so encoded, every trainer takes the universal fine-tune's schedule
    (:func:`~mtlx2neural.universal.fit.use_fine_tune_schedule`) for
    :data:`~mtlx2neural.universal.choice.SCENE_STEP_SHARE` of ``--universal-steps``, on
    :data:`~mtlx2neural.universal.choice.SCENE_FINE_TUNE_ROWS` rows a step; otherwise the
    group runs :data:`WARM_SCHEDULE` of its schedule (the others' encoders train in its encoder phase),
    from the shipped network rather than from random weights. Returns None when no material took the universal path."""
    models = [job.encoder["model"] for job in jobs if job.encoder is not None]
    if not models:
        return None
    model = max(sorted(set(models)), key=models.count)
    weights = load_weights(model)
    encoded, others = [], {}
    for setup, job in zip(setups, jobs):
        if job.encoder is None or job.encoder["model"] != model:
            others[job.name] = (f"its universal network ({job.encoder['model']}) is not the group's"
                                if job.encoder else "own network (not on the universal path)")
            continue
        try:
            load_encoder(setup.trainer, weights)
        except LayoutMismatch as exc:
            others[job.name] = str(exc)
            continue
        encoded.append(job.name)
    if not encoded:
        return None
    load_networks(setups[0].trainer.model, weights)
    if not others:
        steps = max(1, round(jobs[0].encoder["steps"] * SCENE_STEP_SHARE))
        for setup in setups:
            use_fine_tune_schedule(setup.trainer, steps, rows=scene_batch(SCENE_FINE_TUNE_ROWS, len(setups)))
    else:
        steps = max(1, round(WARM_SCHEDULE * setups[0].trainer.cfg.iterations))
        for setup in setups:
            setup.trainer.cfg = dataclasses.replace(setup.trainer.cfg, iterations=steps)
    for setup, job in zip(setups, jobs):
        if job.name in encoded:
            setup.trainer.bake()
    return WarmStart(model, weights["sha256"], encoded, others, steps)


def _group_config(job, materials: int):
    """``job``'s settings in a group of ``materials``: its batch split between the materials of a joint step."""
    return dataclasses.replace(job.cfg, batch=scene_batch(job.cfg.batch, materials))


def _record_fields(job, info: dict, start: WarmStart | None = None) -> dict:
    """The record fields a group gives ``job``'s material: ``network``, and its universal path or why not."""
    fields = {"network": info, "notes": []}
    if start is not None and job.name in start.encoded:
        fields["encoder"] = job.encoder
    elif start is not None and job.encoder is not None:
        fields["notes"].append(f"universal path not taken in the group: {start.others[job.name]}; its encoder "
                               f"trained in the group's schedule")
    return fields


def add_to_network(jobs, network: TrainedNetwork, report=None, failed=None, workers=None) -> list:
    """Each job's material fitted into ``network`` (its encoder and latents alone, the network frozen:
    :func:`~mtlx2neural.train.shared.fit_into_network`), then measured and recorded; records in job order.
    Each record's ``network`` is the group's, with ``added``: the fit's steps and seconds. The fits run in this
    process, the measures in ``workers`` processes (:func:`_measure`)."""
    device = resolve_device(jobs[0].device)
    progress = jobs[0].progress
    shared = network.model.to(device)
    out: list = [None] * len(jobs)
    fitted = []
    if progress:
        print(f"--network scene: {len(jobs)} material(s) fitted into the network of "
              f"{len(network.info.get('materials', []))} trained earlier (id {network.info['id']}): their latents "
              f"alone, {ADDED_FRACTION:.0%} of the schedule, the network unchanged (--force trains it again)",
              flush=True)
    for k, job in enumerate(jobs):
        t0 = time.time()
        try:
            setup = prepare_material(job.source(), job.cfg, Path(job.folder), device, job.allow_missing_textures,
                                     job.resolution, application=job.application)
            fit_into_network(setup.trainer, shared, network.environment_history, progress=progress)
        except KeyboardInterrupt:
            raise TrainingInterrupted(f"interrupted while fitting {job.name} into the scene's network; "
                                      f"run the conversion again") from None
        except Exception as exc:  # noqa: BLE001 - that material's failure; the others are still fitted
            if failed is None:
                raise
            failed(k, exc)
            continue
        info = {**network.info, "added": {"steps": setup.trainer.step, "seconds": round(time.time() - t0, 2)}}
        # prepared without the canonical form (encoder None), as the fit was; the record has no universal path
        fitted.append((k, dataclasses.replace(job, encoder=None, trained={"network": info, "notes": []})))
    _measure(fitted, out, report, failed, workers)
    return out
