"""``--network scene``: every material a conversion trains shares one decoder and one sampler.

The jobs of :func:`~mtlx2neural.pipeline.convert.convert_asset` (one per material to train) are run in
this process instead of one worker per material: each material is prepared as a per-material run
prepares it (:func:`~mtlx2neural.pipeline.material_training.prepare_material`: its reference, training
stack, surface maps, trainer), the trainers are trained together
(:class:`~mtlx2neural.train.shared.SharedTrainer`), and each material is then measured and recorded as
a per-material run records it (:func:`~mtlx2neural.pipeline.material_training.finish_material`), its
record's ``network`` naming the group.

The group's hash: each material's source hash also covers every other material of the group
(:func:`apply_scene_digests`), so a change to any material trains the whole group again, and a
per-material result is never reused as part of a shared network (or the other way round).
"""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path

from mtlx2neural.pipeline.devices import resolve_device
from mtlx2neural.pipeline.material_training import finish_material, prepare_material
from mtlx2neural.train.shared import SharedTrainer, latent_steps, scene_batch
from mtlx2neural.train.trainer import TrainingInterrupted


def apply_scene_digests(plans) -> None:
    """Make each plan's ``digest`` (its source hash) depend on the whole group's (module docstring)."""
    group = "\0".join(sorted(p.digest for p in plans))
    for p in plans:
        p.digest = hashlib.sha256(f"{p.digest}\0network=scene\0{group}".encode()).hexdigest()


def run_scene_jobs(jobs, report=None, failed=None) -> list:
    """Train ``jobs`` (:class:`~mtlx2neural.pipeline.jobs.MaterialJob`) with one shared network; their
    records in job order. A material that cannot be prepared (its graph or textures fail) is passed to
    ``failed(k, exc)`` (None: raised) and left out of the group; a failure of the joint training fails
    every material. ``report(k, record)`` is called as each record is written."""
    if not jobs:
        return []
    device = resolve_device(jobs[0].device)
    progress = jobs[0].progress
    setups, kept = [], []
    for k, job in enumerate(jobs):
        cfg = dataclasses.replace(job.cfg, batch=scene_batch(job.cfg.batch, len(jobs)))
        try:
            setups.append(prepare_material(job.source(), cfg, Path(job.folder), device, job.allow_missing_textures,
                                           job.resolution, application=job.application))
            kept.append(k)
        except Exception as exc:  # noqa: BLE001 - that material's failure; the group trains without it
            if failed is None:
                raise
            failed(k, exc)
    out: list = [None] * len(jobs)
    if not setups:
        return out
    shared = SharedTrainer([s.trainer for s in setups])
    cfg = setups[0].cfg
    if progress:
        print(f"--network scene: {len(setups)} materials share one decoder {cfg.decoder} and one sampler; "
              f"{cfg.iterations} joint steps x {cfg.batch} rows per material, then {latent_steps(cfg.iterations)} "
              f"latent steps per material", flush=True)
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
        return out
    info = {"materials": [jobs[k].name for k in kept], "joint_steps": cfg.iterations,
            "rows_per_material": cfg.batch, "latent_steps": latent_steps(cfg.iterations),
            "seconds": dict(shared.seconds)}
    for k, setup, model in zip(kept, setups, models):
        job = jobs[k]
        extra = {"content_hash": job.content, "warnings": list(job.warnings), "notes": list(job.warnings),
                 "input_hash": job.input_hash, "latent": job.latent, "options": job.options, "network": info}
        try:
            out[k] = finish_material(setup, model, job.digest, extra)
        except Exception as exc:  # noqa: BLE001 - measuring one material failed; the others are kept
            if failed is None:
                raise
            failed(k, exc)
            continue
        if report:
            report(k, out[k])
    return out
