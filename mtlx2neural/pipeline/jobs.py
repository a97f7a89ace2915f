"""Per-material training jobs: one :class:`MaterialJob` per material, run by :func:`run_job`.

Training one material is independent of training another, so every material is one
picklable :class:`MaterialJob` (its MaterialX document travels as XML; documents do not
pickle), run by one function, :func:`run_job`, wherever it runs: in this process, a
spawned pool worker or a Ray task (:mod:`mtlx2neural.pipeline.workers` decides where). A
job writes its results into its material folder (:func:`~mtlx2neural.pipeline.material_training.train_material`)
and returns its :class:`~mtlx2neural.material_record.MaterialRecord`; with an error budget
(``max_error``) it trains decoders from small to large until the HDR FLIP meets the budget
(:mod:`mtlx2neural.pipeline.budget`).

A pool worker's signals are handled here too (:func:`init_pool_worker`): Ctrl-C or SIGTERM
interrupts a running job once, which saves its checkpoint, and is ignored by an idle worker.
"""

from __future__ import annotations

import os
import shutil
import signal
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import MaterialX as mx
import torch

from mtlx2neural.faults import fault_point
from mtlx2neural.graph.ops import Application
from mtlx2neural.material_record import MaterialRecord
from mtlx2neural.pipeline.budget import train_within_budget
from mtlx2neural.pipeline.devices import resolve_device
from mtlx2neural.pipeline.material_training import (
    finish_from_checkpoint,
    train_material,
)
from mtlx2neural.pipeline.source_hash import input_hash
from mtlx2neural.scene import MaterialSource
from mtlx2neural.train.config import TrainConfig


@dataclass
class Shipped:
    """What a remote worker (:attr:`MaterialJob.ship`) returns: the record and the folder's files."""

    record: MaterialRecord
    files: dict[str, bytes]
    """{file name: content} of the material folder the job trained in."""


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
    """Planning warnings (a capped grid): recorded in the record's ``warnings`` and ``notes``."""
    latent: dict | None = None
    """The plan's grid decision (:meth:`mtlx2neural.pipeline.plan.MaterialPlan.latent_info`): the record's ``latent``."""
    threads: int | None = None
    """torch threads in the worker (None: leave torch's default)."""
    ship: bool = False
    """Train in a temporary folder and return its files with the record (:class:`Shipped`; a remote worker)."""
    checkpoint: bytes | None = None
    """With ``ship`` and ``resume``: the checkpoint to resume from."""
    progress_queue: object = None
    """A pool worker sends (index, step, total, loss, phase) here for the parent's progress bars."""
    index: int = 0
    options: dict | None = None
    """The conversion's options (:func:`mtlx2neural.pipeline.options.options_record`): the record's ``options``."""
    input_hash: str | None = None
    """:func:`~mtlx2neural.pipeline.source_hash.input_hash` of the material: the record's ``input_hash``."""
    stage_file: str | None = None
    """The USD stage whose bound meshes provide the geometry the graph reads (``MaterialSource.stage_file``)."""
    application: Application | None = None
    """The instant ``time``/``frame`` nodes fold to (``--frame``/``--fps``; None: frame 1 at 24 fps)."""
    encoder: dict | None = None
    """The universal path's choice (:meth:`~mtlx2neural.universal.choice.EncoderChoice.record`), None: its own training."""
    encoder_note: str | None = None
    """Why ``--encoder universal`` was not taken (:attr:`~mtlx2neural.universal.choice.EncoderChoice.reason`), None
    when it was or was not asked: printed when the job starts and kept in the record's ``notes``."""
    measured: bool = False
    """A measured BRDF: ``source_file`` is its MERL table and ``document_xml`` is empty."""
    preview_surface: bool = False
    """The input's own UsdPreviewSurface is the material's fallback (``MaterialSource.preview_surface``)."""
    trained: dict | None = None
    """Set for a material a shared network already trained (``--network scene``): its checkpoint is in
    ``folder``, and the job only measures and records it
    (:func:`~mtlx2neural.pipeline.material_training.finish_from_checkpoint`); the further record fields
    (``network``, ``encoder``, ``notes``)."""
    part: str | None = None
    """With ``trained``: measure only one part (``"energy"`` or ``"record"``:
    :func:`~mtlx2neural.pipeline.material_training.finish_from_checkpoint`); the job then returns that part
    and writes no record."""

    def source(self):
        """The :class:`~mtlx2neural.scene.MaterialSource` rebuilt from the XML (or the MERL file's path)."""
        if self.measured:
            return MaterialSource(self.name, None, self.material, self.source_file, [], measured=True)
        doc = mx.createDocument()
        mx.readFromXmlString(doc, self.document_xml)
        return MaterialSource(self.name, doc, self.material, self.source_file, list(self.bound_prims),
                              stage_file=self.stage_file, preview_surface=self.preview_surface)


def make_job(plan, folder: Path, cfg: TrainConfig, **options) -> MaterialJob:
    """The job for a :class:`mtlx2neural.pipeline.plan.MaterialPlan` (``options``: the other fields)."""
    src = plan.source
    measured = getattr(src, "measured", False)
    return MaterialJob(src.name, src.material, src.source_file, list(src.bound_prims),
                       "" if measured else mx.writeToXmlString(src.document), str(folder), cfg, plan.digest,
                       plan.content, tuple(plan.grid), warnings=list(plan.warnings), latent=plan.latent_info(),
                       stage_file=getattr(src, "stage_file", None), input_hash=input_hash(src), measured=measured,
                       preview_surface=getattr(src, "preview_surface", False),
                       encoder=plan.encoder.record() if plan.encoder.universal else None,
                       encoder_note=(f"--encoder universal not taken: {plan.encoder.text}" if plan.encoder.reason
                                     else None), **options)


def _merged(extra: dict, more: dict) -> dict:
    """``extra`` with ``more``'s fields, its ``notes`` appended."""
    return {**extra, **more, "notes": [*extra.get("notes", []), *more.get("notes", [])]}


def _trained_seconds(network: dict) -> float:
    """The training time of a shared network's material: its own fit when it was added to a kept network,
    else the group's phases."""
    added = network.get("added")
    return added["seconds"] if added else sum(network["seconds"].values())


def run_job(job: MaterialJob) -> MaterialRecord | Shipped:
    """Train one material (any runner calls this); returns its record (also in ``summary.json``), or
    with ``job.ship`` a :class:`Shipped` that also carries the folder's files (with ``job.part``: that part
    of the measures, unwritten)."""
    listener = None
    if job.threads:
        torch.set_num_threads(job.threads)
    if job.progress_queue is not None:
        q, i = job.progress_queue, job.index
        listener = lambda step, total, rec: q.put((i, step, total, rec["loss_brdf"], rec["phase"]))  # noqa: E731
    fault_point("job", job.name)  # tests: a worker that dies abruptly (mtlx2neural.faults)
    src = job.source()
    device = resolve_device(job.device)
    folder = Path(tempfile.mkdtemp(prefix="mtlx2neural_")) if job.ship else Path(job.folder)
    folder.mkdir(parents=True, exist_ok=True)
    if job.ship and job.checkpoint is not None:
        (folder / "checkpoint.pt").write_bytes(job.checkpoint)
    extra = {"content_hash": job.content, "warnings": list(job.warnings),
             "notes": [*job.warnings, *([job.encoder_note] if job.encoder_note else [])],
             "input_hash": job.input_hash, "latent": job.latent, "options": job.options}
    if job.encoder_note and job.progress:
        print(f"{job.name}: {job.encoder_note}", flush=True)
    try:
        with _running():
            if job.trained is not None:
                record = finish_from_checkpoint(src, job.cfg, folder, device, job.allow_missing_textures,
                                                job.digest, job.resolution, _merged(extra, job.trained),
                                                application=job.application, canonical=job.encoder is not None,
                                                trained_seconds=_trained_seconds(job.trained["network"]),
                                                part=job.part)
            elif job.max_error is None:
                _, record = train_material(src, job.cfg, folder, device, job.resume, job.progress,
                                           job.allow_missing_textures, job.digest, job.resolution, extra,
                                           application=job.application, listener=listener, encoder=job.encoder)
            else:
                record = train_within_budget(src, job.cfg, folder, device, job.resume, job.progress,
                                             job.allow_missing_textures, job.digest, job.max_error,
                                             job.resolution, extra, application=job.application,
                                             listener=listener)
        if job.ship:
            return Shipped(record, {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()})
        return record
    finally:
        if job.ship:
            shutil.rmtree(folder, ignore_errors=True)


# ----------------------------------------------------------------------------- a pool worker's signals

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


def init_pool_worker(threads: int, nice: int = 0) -> None:
    """A spawned pool worker's initializer: Ctrl-C (SIGINT) or SIGTERM interrupts a running job only, which
    saves its checkpoint; ``threads`` torch threads; ``nice``: a lower scheduling priority (POSIX ``nice``
    increment; a pool started ahead of its jobs takes only the CPU its parent leaves)."""
    signal.signal(signal.SIGINT, _pool_sigint)
    signal.signal(signal.SIGTERM, _pool_sigint)
    torch.set_num_threads(threads)
    if nice and hasattr(os, "nice"):
        os.nice(nice)


def pool_worker_started() -> bool:
    """A no-op job: submitted once per worker of a pool started ahead of its jobs, so that each starts now."""
    return True
