"""The shared network (``train.shared``): one decoder and one sampler for several materials, each with its
own latents; the phases keep the sharing, the latent fine-tune leaves the network alone (tiny CPU runs)."""

from __future__ import annotations

import math

import pytest
import torch
from materials import layered_spheres_material

from mtlx2neural.train.config import preset
from mtlx2neural.train.shared import (
    FLOOR_PREFETCH,
    SCENE_MIN_ROWS,
    SharedTrainer,
    latent_steps,
    scene_batch,
)
from mtlx2neural.train.trainer import Trainer

NAMES = ("CarPaint", "Plastic")


@pytest.fixture(scope="module")
def materials():
    return [layered_spheres_material(n) for n in NAMES]


def _trainers(materials, tmp_path, **overrides):
    cfg = preset("fast", iterations=80, batch=512, seed=3, **overrides)
    return [Trainer(ref, stack, cfg, tmp_path / name) for (ref, stack), name in zip(materials, NAMES)]


def test_batch_split_and_floor():
    assert scene_batch(2048, 2) == 1024 and scene_batch(2048, 23) == 512 and scene_batch(512, 23) == SCENE_MIN_ROWS
    assert latent_steps(1000) == 200


def test_one_network_every_material_its_own_latents(materials, tmp_path, monkeypatch):
    trainers = _trainers(materials, tmp_path)
    shared = SharedTrainer(trainers)
    # the latent fine-tune must not move the shared network: snapshot it when that phase starts
    snapshots, moved = [], []
    real = shared.fit_latents

    def fit_latents(steps):
        decoder = trainers[0].model.decoder
        latents = [t.model.latents.levels[0].detach().clone() for t in trainers]
        snapshots.append({k: v.clone() for k, v in decoder.state_dict().items()})
        real(steps)
        snapshots.append({k: v.clone() for k, v in decoder.state_dict().items()})
        moved.extend(not torch.equal(before, t.model.latents.levels[0]) for before, t in zip(latents, trainers))

    monkeypatch.setattr(shared, "fit_latents", fit_latents)
    models = shared.run(progress=False)
    a, b = models
    assert a.decoder is b.decoder and a.sampler is b.sampler
    assert a.latents is not b.latents and not torch.equal(a.latents.levels[0], b.latents.levels[0])
    # the latent fine-tune: the network bit-identical before and after (environment head aside:
    # it is fitted afterwards)
    for before, after in zip(snapshots[::2], snapshots[1::2]):
        assert all(torch.equal(before[k], after[k]) for k in before)
    assert len(snapshots) == 2 and moved == [True, True]  # one fine-tune of every material's latents
    # the joint phase trained: the mean loss fell (measured ~0.6x over 80 steps; bound 0.9x)
    first, last = shared.history[0]["loss_brdf"], shared.history[-1]["loss_brdf"]
    assert last < 0.9 * first, (first, last)
    # each material's checkpoint holds the same network
    ck = [torch.load(t.checkpoint_path, weights_only=False)["model"] for t in trainers]
    shared_keys = [k for k in ck[0] if k.startswith(("decoder.", "sampler."))]
    assert shared_keys and all(torch.equal(ck[0][k], ck[1][k]) for k in shared_keys)
    assert set(shared.seconds) == {"joint", "latents", "environment"}
    # both models still answer on their own
    wi = torch.nn.functional.normalize(torch.rand(64, 3) + 0.05, dim=-1)
    for m in models:
        assert bool(torch.isfinite(m.eval(wi, wi.flip(1).abs())).all())


def test_rows_drawn_ahead_once_the_mollification_is_at_its_floor(materials, tmp_path, monkeypatch):
    """Each material draws its rows one step at a time while its mollification angle decays, then
    FLOOR_PREFETCH steps' rows per call to the reference (the same rows' distribution at a lower cost)."""
    trainers = _trainers(materials, tmp_path)
    shared = SharedTrainer(trainers)
    monkeypatch.setattr(shared, "fit_latents", lambda steps: None)  # the joint phase only
    draws = {id(t): [] for t in trainers}
    for t in trainers:
        real = t.draw_rows
        monkeypatch.setattr(t, "draw_rows", lambda n, t=t, real=real: draws[id(t)].append((t.step, n)) or real(n))
    shared.run(progress=False)
    probe = trainers[0]
    floor = next(s for s in range(probe.cfg.iterations) if (setattr(probe, "step", s) or
                 probe.mollify_angle() <= math.radians(probe.cfg.mollify_min_degrees)))
    assert 0 < floor < probe.cfg.iterations // 2
    rows = probe.cfg.batch
    for t in trainers:  # two materials: both in every joint step
        expected = [(s, rows) for s in range(floor)]
        expected += [(s, rows * FLOOR_PREFETCH) for s in range(floor, probe.cfg.iterations, FLOOR_PREFETCH)]
        assert draws[id(t)] == expected


def test_refuses_materials_of_another_shape(materials, tmp_path):
    first = _trainers(materials[:1], tmp_path)[0]
    other = Trainer(*materials[1], preset("fast", iterations=80, batch=512, decoder="2x32"), tmp_path / "other")
    with pytest.raises(ValueError, match="decoder"):
        SharedTrainer([first, other])


def test_each_materials_energy_is_calibrated_after_the_latent_fine_tune(materials, tmp_path, monkeypatch):
    """A balanced shared run (200 steps, the balance's shortest) calibrates each material's codes once, after the
    latent fine-tune that would otherwise move them again: every level's probe ratio ends inside the band (0.005:
    the calibration's two Gauss-Newton steps, measured within 0.001 of its edge)."""
    from mtlx2neural.train import energy_balance as eb

    cfg = preset("fast", iterations=200, batch=256, seed=3, environment_fraction=0.0, preview_iterations=0)
    trainers = [Trainer(ref, stack, cfg, tmp_path / name) for (ref, stack), name in zip(materials, NAMES)]
    shared = SharedTrainer(trainers)
    events = []
    real_fit = shared.fit_latents
    monkeypatch.setattr(shared, "fit_latents", lambda steps: (events.append("latents"), real_fit(steps)))
    for t in trainers:
        real = t.calibrate_energy
        monkeypatch.setattr(t, "calibrate_energy", lambda real=real, name=t.out_dir.name: (events.append(name), real()))
    shared.run(progress=False)
    assert events == ["latents", *NAMES]
    for t in trainers:
        ratios = t.balance.ratios(t.model)
        assert bool(((ratios > eb.CALIBRATION_LOW - 0.005) & (ratios < eb.CALIBRATION_HIGH + 0.005)).all()), ratios
        assert "energy_calibrated_from" in t.history[-1]
