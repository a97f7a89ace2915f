"""A trained material measured in two parts (``finish_from_checkpoint(part=...)``: its record, and its energy
check), as ``--network scene`` measures it in a pool, gives the record measured whole: the same figures, the
same warnings, and nothing written until the parts are joined (a tiny textured material, small views)."""

from __future__ import annotations

import dataclasses
import shutil

from test_jobs import textured_asset

from mtlx2neural.material_record import RECORD_FILE
from mtlx2neural.pipeline import in_scene_measure, material_training
from mtlx2neural.pipeline.jobs import make_job
from mtlx2neural.pipeline.material_training import (
    apply_energy,
    finish_from_checkpoint,
    train_material,
)
from mtlx2neural.pipeline.plan import plan_materials
from mtlx2neural.scene import load_asset
from mtlx2neural.train.config import preset

TIMING = ("seconds", "worker")  # wall times and the process: what differs between two measures of one model


def test_the_parts_joined_are_the_whole_record(tmp_path, monkeypatch):
    views, in_scene = material_training.summary_views, in_scene_measure.compare_in_scene
    monkeypatch.setattr(material_training, "summary_views", lambda *a, **k: views(*a, **k, res=24, spp=2))
    monkeypatch.setattr(in_scene_measure, "compare_in_scene", lambda *a, **k: in_scene(*a, **k, res=24, spp=2))
    asset = textured_asset(tmp_path)
    cfg = preset("fast", iterations=20, batch=256, preview_iterations=0)
    (plan,) = plan_materials(load_asset(str(asset)).materials, cfg, asset=str(asset))
    src = make_job(plan, tmp_path / "M", cfg).source()
    train_material(src, cfg, tmp_path / "M", "cpu", False, False, False, plan.digest, resolution=(8, 8),
                   preview=False)
    folders = {}
    for name in ("whole", "record", "energy"):
        folders[name] = tmp_path / name
        shutil.copytree(tmp_path / "M", folders[name])
        (folders[name] / RECORD_FILE).unlink()  # the training's record: each measure writes its own, or none

    def measure(part):
        return finish_from_checkpoint(src, cfg, folders[part or "whole"], "cpu", False, plan.digest, (8, 8),
                                      {"notes": []}, part=part)

    whole = measure(None)
    record, energy = measure("record"), measure("energy")
    assert not (folders["record"] / RECORD_FILE).exists() and not (folders["energy"] / RECORD_FILE).exists()
    assert (folders["whole"] / RECORD_FILE).is_file()
    assert record.energy is None and len(energy.levels) == len(whole.energy["by_level"]) > 1
    joined = apply_energy(record, energy)
    a, b = dataclasses.asdict(joined), dataclasses.asdict(whole)
    for key in TIMING:
        a.pop(key), b.pop(key)
    assert a == b
    assert any("energy check" in w for w in whole.warnings)  # 20 steps: far from the reference, and warned
