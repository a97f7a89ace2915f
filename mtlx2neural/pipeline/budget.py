"""An error budget (``--max-error``): the smallest decoder whose HDR FLIP meets it.

The decoder sizes of :data:`~mtlx2neural.pipeline.plan.DECODERS` train from small to large
(:func:`choose_decoder`) until one's figure (:meth:`~mtlx2neural.material_record.MaterialRecord.budget_error`:
in the scene when the source's stage gives one, else the analytic views' mean) meets the budget.
"""

from __future__ import annotations

import dataclasses
import math
import os
import shutil
from collections.abc import Callable
from pathlib import Path

from mtlx2neural.baseline.analytic_model import BASELINE_FILE
from mtlx2neural.graph.ops import Application
from mtlx2neural.material_record import RECORD_FILE, MaterialRecord, write_record
from mtlx2neural.pipeline.material_training import add_preview, train_material
from mtlx2neural.pipeline.plan import DECODERS
from mtlx2neural.textures.surface_maps import SURFACE_FILE
from mtlx2neural.train.config import TrainConfig


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


BUDGET_FOLDER = "budget"
"""Sub-folder of a material folder where the decoder sizes of an error budget train."""


def train_within_budget(src, cfg: TrainConfig, folder: Path, device: str, resume: bool, progress: bool,
                        allow_missing_textures: bool, digest: str, max_error: float,
                        resolution: tuple[int, int] | None = None, extra: dict | None = None,
                        application: Application | None = None, listener=None) -> MaterialRecord:
    """Train the smallest decoder of :data:`~mtlx2neural.pipeline.plan.DECODERS` whose HDR FLIP is at
    most ``max_error`` (:func:`choose_decoder`); returns its record. The FLIP is the in-scene one when
    the source's stage gives one, else the analytic views' mean (:meth:`MaterialRecord.budget_error`).

    Each size trains into ``folder/budget/<size>/``; the chosen one's files then move up
    into ``folder`` and the others are deleted. The record adds ``budget`` (the budget,
    the FLIP and seconds of every size tried, and ``metric``: which figure was checked,
    ``flip_in_scene`` or ``flip_mean``) and ``budget_met``; a missed budget is
    also a warning in ``warnings`` and ``notes``.
    """
    (folder / RECORD_FILE).unlink(missing_ok=True)
    (folder / SURFACE_FILE).unlink(missing_ok=True)  # the chosen run's maps (if any) move up below
    runs: dict[str, MaterialRecord] = {}

    def attempt(decoder: str) -> float:
        sub = folder / BUDGET_FOLDER / decoder
        _, run = train_material(src, dataclasses.replace(cfg, decoder=decoder), sub, device, resume, progress,
                                allow_missing_textures, digest, resolution, extra, preview=False,
                                application=application, listener=listener)
        runs[decoder] = run
        err = run.budget_error()
        if progress:
            where = "in scene" if run.flip_in_scene is not None else "analytic views"
            print(f"{src.name}: decoder {decoder}: HDR FLIP {err:.4f} ({where}; "
                  f"{'meets' if err <= max_error else 'misses'} the budget {max_error})", flush=True)
        return err

    decoder, flips = choose_decoder(attempt, max_error)
    met = bool(flips[decoder] <= max_error)
    for p in (folder / BUDGET_FOLDER / decoder).iterdir():
        os.replace(p, folder / p.name)
    shutil.rmtree(folder / BUDGET_FOLDER, ignore_errors=True)
    record = runs[decoder]
    if cfg.preview_iterations > 0:
        record = add_preview(src, folder, device, allow_missing_textures, record.resolution, cfg.seed,
                             record, cfg.preview_iterations, application, cfg.footprint_samples)
    else:
        (folder / BASELINE_FILE).unlink(missing_ok=True)
    record = dataclasses.replace(
        record, budget_met=met, seconds=round(sum(r.seconds for r in runs.values()), 1),
        budget={"max_error": max_error, "flip_by_decoder": flips,
                "metric": "flip_in_scene" if runs[decoder].flip_in_scene is not None else "flip_mean",
                "seconds_by_decoder": {k: r.seconds for k, r in runs.items()}, "met": met})
    if not met:
        record = record.with_warning(
            f"HDR FLIP budget {max_error} not met: even the largest decoder, {DECODERS[-1]}, reaches "
            f"{flips[DECODERS[-1]]:.4f}; kept {decoder} ({flips[decoder]:.4f}). Train longer "
            f"(--preset standard on a CPU, balanced on a GPU, or --iterations) or relax --max-error")
    write_record(folder, record)
    return record
