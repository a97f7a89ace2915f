"""The energy balance: the asymmetric log-L1, its schedule, its measurement and its moves, and a textured
sample that keeps its energy with ``fast``."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
from materials import layered_spheres_material

from mtlx2neural.contract import ShadingPoint
from mtlx2neural.train import energy_balance as eb
from mtlx2neural.train.config import preset
from mtlx2neural.train.losses import log_l1_terms
from mtlx2neural.train.trainer import Trainer


@pytest.fixture(scope="module")
def carpaint():
    return layered_spheres_material("CarPaint")


class Scaled:
    """A stand-in model: the reference itself times ``scale`` (its albedo is the reference's times the scale);
    it samples and has the density of the reference."""

    def __init__(self, reference, scale: float):
        self.ref, self.scale = reference, scale

    def eval(self, wi, wo, at=None):
        return self.scale * self.ref.eval(wi, wo, ShadingPoint(uv=at.uv))

    def pdf(self, wi, wo, at=None):
        return self.ref.pdf(wi, wo, ShadingPoint(uv=at.uv))

    def sample(self, wi, u, at=None):
        return self.ref.sample(wi, u, ShadingPoint(uv=at.uv))


def test_the_asymmetric_log_l1_seeks_its_quantile():
    """Over right-skewed targets (log-normal), the constant prediction that minimises the loss is the targets'
    tau-quantile: the pinball loss in log space. Grid step 0.0067 in log; the empirical minimiser is a sample
    quantile itself, so 0.015 (two steps) covers the grid alone. tau 0.5 is plain log-L1, bit for bit."""
    g = torch.Generator().manual_seed(0)
    y = torch.exp(torch.randn(5000, generator=g, dtype=torch.float64))
    grid = torch.linspace(-2.0, 2.0, 601, dtype=torch.float64)
    preds, targets = torch.exp(grid)[:, None].expand(-1, y.shape[0]), y[None].expand(grid.shape[0], -1)
    for tau in (0.3, 0.5, 0.7):
        best = float(grid[int(torch.argmin(log_l1_terms(preds, targets, 1e-9, tau).mean(1)))])
        assert abs(best - float(torch.quantile(torch.log(y), tau))) < 0.015, tau
    y = y[:, None].expand(-1, 3)
    pred = torch.rand(64, 3, generator=g)
    assert torch.equal(log_l1_terms(pred, y[:64], 1e-4, tau=0.5), log_l1_terms(pred, y[:64], 1e-4))
    # A per-row quantile ([N, 1]) weighs each row's error by its own: rows below their target at tau 0.8 cost 4x
    # what they cost at 0.2.
    low = torch.zeros(2, 3) + 0.5
    terms = log_l1_terms(low, torch.ones(2, 3), 1e-4, tau=torch.tensor([[0.8], [0.2]]))
    assert torch.allclose(terms[0], 4 * terms[1])


def test_updates_fall_from_thirty_percent_every_twentieth_never_after_the_last_step():
    assert [s for s in range(1, 1001) if eb.update_due(s, 1000)] == list(range(300, 1000, 50))
    assert [s for s in range(1, 201) if eb.update_due(s, 200)] == list(range(60, 200, 10))
    assert not any(eb.update_due(s, eb.MIN_ITERATIONS - 1) for s in range(0, eb.MIN_ITERATIONS))


def test_the_balance_measures_the_energy_and_moves_the_quantile_against_it(carpaint):
    """The reference itself measures 1 (the estimators are the energy check's; 3 % covers their Monte Carlo
    error on the coat); the reference at 0.8 measures 0.8 and raises the quantile by the largest move; at 1.25
    it lowers it; smoothing keeps a repeated measurement's move."""
    ref, _ = carpaint
    balance = eb.EnergyBalance(ref, 1, (1, 1), gain=0.3, seed=0)
    same = float(balance.ratios(Scaled(ref, 1.0))[0])
    assert abs(same - 1.0) < 0.03, same
    assert abs(float(balance.ratios(Scaled(ref, 0.8))[0]) - 0.8 * same) < 1e-4
    balance.update(Scaled(ref, 0.8))
    assert math.isclose(float(balance.taus[0]), 0.5 + eb.MAX_MOVE, abs_tol=1e-6)
    balance.update(Scaled(ref, 0.8))
    assert math.isclose(float(balance.taus[0]), 0.5 + 2 * eb.MAX_MOVE, abs_tol=1e-6)
    down = eb.EnergyBalance(ref, 1, (1, 1), gain=0.3, seed=0)
    down.update(Scaled(ref, 1.25))
    assert float(down.taus[0]) < 0.5
    kept = eb.EnergyBalance(ref, 1, (1, 1), gain=0.3, seed=0)
    kept.update(Scaled(ref, 1.0))
    assert abs(float(kept.taus[0]) - 0.5) <= 0.3 * 0.03 + 1e-6  # gain x the ratio's error at most
    assert torch.equal(kept.row_tau(torch.tensor([0, 0])), kept.taus[[0, 0]])
    restored = eb.EnergyBalance(ref, 1, (1, 1), gain=0.3, seed=0)
    restored.load_state_dict(balance.state_dict())
    assert torch.equal(restored.taus, balance.taus) and torch.allclose(restored.smoothed, balance.smoothed)


class LevelScaled(Scaled):
    """The reference times 1 + 0.1 x the MIP level it is read at (``at.lod``, one per row)."""

    def __init__(self, reference):
        super().__init__(reference, 1.0)

    def eval(self, wi, wo, at=None):
        return (1.0 + 0.1 * at.lod)[:, None] * self.ref.eval(wi, wo, ShadingPoint(uv=at.uv))


def test_one_call_reads_each_row_at_its_own_level(carpaint):
    """Three levels' probe rows measured in one call: a model whose energy is 1, 1.1 and 1.2 times the reference's at
    levels 0, 1 and 2 reads so, each level within 3 % (the estimators' Monte Carlo error on the coat, as above)."""
    ref, _ = carpaint
    ratios = eb.EnergyBalance(ref, 3, (4, 4), gain=0.3, seed=0).ratios(LevelScaled(ref))
    assert torch.allclose(ratios, torch.tensor([1.0, 1.1, 1.2]), rtol=0.03), ratios


class LatentScaled(Scaled):
    """The reference times exp(4 x the first channel of a latent pyramid's code at the row's uv and MIP level): a
    stand-in whose level energies its latents set, as a trained model's do."""

    def __init__(self, reference, pyramid):
        super().__init__(reference, 1.0)
        self.latents = pyramid

    def eval(self, wi, wo, at=None):
        code = self.latents.fetch(at.uv, at.lod.round().long())
        return torch.exp(4.0 * code[:, :1]) * self.ref.eval(wi, wo, ShadingPoint(uv=at.uv))


def test_the_calibration_brings_every_level_to_the_references_energy_by_shifting_its_codes(carpaint):
    """Levels 0-3 of an 8 x 8 pyramid at 0.8, 1.15, 0.9 and 1.05 times the reference's energy (with texel to texel
    spread): after the calibration the levels under the band's floor (1) come to it, each within 0.5 % (two
    Gauss-Newton steps on an exact log-linear model: the tolerance is the rounding of the estimate's fixed
    directions, far below it), a second probe set of its own seed reads them within 3 % (the estimators' error on
    the coat, as above), the levels over 1 (1.15 too: the band has no upper edge) are left as they were, and only
    the channel the energy depends on moved, by the same amount at every texel of a level."""
    from mtlx2neural.model.latent import LatentPyramid

    ref, _ = carpaint
    torch.manual_seed(0)
    pyramid = LatentPyramid(8, 8, channels=2, init_std=0.02)
    scales = (0.8, 1.15, 0.9, 1.05)
    with torch.no_grad():
        for lv, scale in zip(pyramid.levels, scales):
            lv[0] += 0.25 * math.log(scale) - lv[0].mean()
            lv[1] += 0.5  # codes of a trained model's size (the shift's cap is a share of their norm)
    before = [lv.detach().clone() for lv in pyramid.levels]
    start = before
    model = LatentScaled(ref, pyramid)
    balance = eb.EnergyBalance(ref, 4, (8, 8), gain=0.3, seed=0)
    measured = balance.ratios(model)
    assert torch.allclose(measured, torch.tensor(scales), rtol=0.03)
    after = torch.tensor(balance.calibrate(model)[1])
    assert eb.CALIBRATION_HIGH == math.inf
    want = torch.tensor([eb.CALIBRATION_LOW, float(measured[1]), eb.CALIBRATION_LOW, float(measured[3])])
    assert torch.allclose(after, want, atol=0.005), after
    other = eb.EnergyBalance(ref, 4, (8, 8), gain=0.3, seed=11).ratios(model)
    assert torch.allclose(other, want, atol=0.03), other
    for k, (lv, s0, b0) in enumerate(zip(pyramid.levels, start, before)):
        moved = lv.detach() - s0
        assert torch.equal(lv.detach()[1], b0[1])  # the channel that sets no energy stays
        if k in (1, 3):  # inside the band
            assert torch.equal(moved, torch.zeros_like(moved))
        else:
            assert float(moved[0].abs().max()) > 0.005
            assert torch.allclose(moved[0], moved[0].mean().expand_as(moved[0]))


class Wavy(LatentScaled):
    """The reference times exp(0.3 sin(40 x the first channel)): an energy whose first-order step overshoots."""

    def eval(self, wi, wo, at=None):
        code = self.latents.fetch(at.uv, at.lod.round().long())
        return torch.exp(0.3 * torch.sin(40.0 * code[:, :1])) * self.ref.eval(wi, wo, ShadingPoint(uv=at.uv))


class Flat(LatentScaled):
    """The reference times 0.8 exp(1e-4 x the first channel): an energy its codes barely move."""

    def eval(self, wi, wo, at=None):
        code = self.latents.fetch(at.uv, at.lod.round().long())
        return 0.8 * torch.exp(1e-4 * code[:, :1]) * self.ref.eval(wi, wo, ShadingPoint(uv=at.uv))


def test_the_calibration_never_leaves_a_level_worse_nor_pushes_its_codes_far(carpaint):
    """Where the first-order step does not hold (an energy periodic in the codes, each level near a trough of it),
    every level ends at most as far from the band as it started (1e-3: the probe's rounding); where the codes barely
    move the energy (an uncapped step would move them by about 2000, a capped one gains 1e-5 of energy), the level,
    not brought half way to the band, keeps its trained codes."""
    from mtlx2neural.model.latent import LatentPyramid

    ref, _ = carpaint
    torch.manual_seed(1)
    pyramid = LatentPyramid(8, 8, channels=2, init_std=0.005)
    with torch.no_grad():
        for k, lv in enumerate(pyramid.levels):
            lv[0] += -math.pi / 80 + 0.01 * k  # sin(40 x) near -1 at level 0, -0.35 at level 3
    balance = eb.EnergyBalance(ref, 4, (8, 8), gain=0.3, seed=0)
    model = Wavy(ref, pyramid)
    excess = lambda r: eb._band_excess(torch.log(torch.as_tensor(r))).abs()
    before = excess(balance.ratios(model))
    assert float(before.max()) > 0.05
    after = excess(balance.calibrate(model)[1])
    assert bool((after <= before + 1e-3).all()), (before, after)

    flat = LatentPyramid(8, 8, channels=2, init_std=0.3)
    trained = [lv.detach().clone() for lv in flat.levels]
    model = Flat(ref, flat)
    _, ratios = balance.calibrate(model)
    assert all(r < 0.85 for r in ratios), ratios  # still far under the band: the codes cannot carry it
    for lv, old in zip(flat.levels, trained):
        assert torch.equal(lv.detach(), old)  # no nearer the band after the capped steps: trained codes back


def test_a_training_run_updates_its_balance_draws_none_of_its_random_numbers_and_resumes_it(carpaint, tmp_path):
    """With ``energy_gain`` the curves record each update (from 30 % of the run, every twentieth), the quantile
    moves off 0.5, the checkpoint keeps it and a resumed run starts from it; the rows drawn are the same as
    without a balance (the probe set has a generator of its own), so only the loss differs."""
    import csv
    import dataclasses

    ref, stack = carpaint
    cfg = preset("fast", iterations=200, batch=128, seed=3, checkpoint_every=1000, environment_fraction=0.0,
                 preview_iterations=0)
    on = Trainer(ref, stack, cfg, tmp_path / "on")
    on.run(progress=False)
    updates = [r for r in on.history if "energy_tau_min" in r]
    assert [r["step"] for r in updates] == list(range(60, 200, 10))
    assert all(0 < r["energy_ratio_min"] < 10 and eb.TAU_MIN <= r["energy_tau_min"] <= r["energy_tau_max"]
               <= eb.TAU_MAX for r in updates)
    assert float(on.balance.taus[0]) != 0.5
    rows = list(csv.DictReader(open(tmp_path / "on" / "training_curves.csv")))
    assert sum(1 for r in rows if r["energy_tau_min"]) == len(updates)
    # the calibration after the last step (EnergyBalance.calibrate), in the last record: its one level is brought
    # into the band, or left where it was inside it
    last = on.history[-1]
    assert last["step"] == 200 and eb.CALIBRATION_LOW - 0.005 <= last["energy_ratio_min"] <= eb.CALIBRATION_HIGH + 0.005
    if eb.CALIBRATION_LOW <= last["energy_calibrated_from"] <= eb.CALIBRATION_HIGH:
        assert last["energy_ratio_min"] == last["energy_calibrated_from"]
    assert rows[-1]["energy_calibrated_from"] == str(last["energy_calibrated_from"])
    off = Trainer(ref, stack, dataclasses.replace(cfg, energy_gain=0.0), tmp_path / "off")
    off.run(progress=False)
    assert off.balance is None and not any("energy_ratio_min" in r or "energy_calibrated_from" in r
                                           for r in off.history)
    assert torch.equal(on.gen.get_state(), off.gen.get_state())
    saved = torch.load(tmp_path / "on" / "checkpoint.pt", weights_only=False)["energy_balance"]
    assert saved["taus"] == on.balance.taus.tolist()
    again = Trainer(ref, stack, cfg, tmp_path / "on")
    assert again.resume() and again._balance_state["taus"] == saved["taus"]


@pytest.mark.slow
def test_fast_keeps_a_brushed_metals_energy(tmp_path):
    """The textured sample's BrushedMetal (anisotropic metal, roughness and normal maps), ``fast``, seed 0: every
    MIP level keeps most of the reference's directional albedo (the energy check, 64 texels x 4 views per level).
    With the 512² textures a test process writes (``mitsuba_samples.sample_asset``): plain log-L1 (``energy_gain``
    0) keeps 0.91-0.94, the balance 0.97-1.01; with the 1024² ones of ``samples/make_textured_sample.py``, 0.85-0.88
    and 0.98-1.02. Bound 0.94: 3 % under the balance's lowest level at 512², 3 % over plain log-L1's lowest; the
    issue's goal (0.95) is measured at 1024² (BENCHMARKS.md)."""
    from mitsuba_samples import sample_asset

    from mtlx2neural.graph import compile_material
    from mtlx2neural.pipeline.plan import latent_resolution
    from mtlx2neural.reference import ReferenceMaterial
    from mtlx2neural.scene import find_material
    from mtlx2neural.textures.parameter_stack import build_parameter_stack
    from mtlx2neural.verify.energy import energy_check

    src = find_material(sample_asset("textured"), "/World/Looks/BrushedMetal")
    compiled = compile_material(src.document, src.material)
    cfg = preset("fast", seed=0, environment_fraction=0.0, preview_iterations=0)
    stack = build_parameter_stack(compiled, resolution=latent_resolution(compiled, cfg))
    ref = ReferenceMaterial(compiled)
    model = Trainer(ref, stack, cfg, tmp_path).run(progress=False)
    check = energy_check(ref, model, tuple(stack.resolution), len(model.latents.levels))
    assert check.min_ratio >= 0.94, [round(lv.ratio, 3) for lv in check.levels]


@pytest.mark.slow
def test_fast_keeps_the_near_mirrors_energy_at_every_level(tmp_path):
    """The near-mirror sample (metalness 1, roughness 0.02-0.3 from a texture, a normal map), ``fast``, seed 0: every
    MIP level keeps the reference's energy in the energy check (its own texels, not the balance's probe). Without
    the calibration it kept 0.937 / 1.037 at its lowest level (seeds 0 / 1), with it 0.988 / 1.037; before the
    balance 0.79-0.85, and plain log-L1 with an earlier fast trained it black. Bound 0.94: the calibration brings
    every level to at least 1 on the probe, and the check read the calibrated model's lowest level at 0.981-0.993
    over four texel seeds (seed 1's model: 1.017-1.035), so 4 % under the lowest of them; the uncalibrated model's
    0.937 is under it. (The issue's floor for this sample is 0.90.)"""
    from mtlx2neural.graph import compile_material
    from mtlx2neural.pipeline.plan import latent_resolution
    from mtlx2neural.reference import ReferenceMaterial
    from mtlx2neural.scene import find_material
    from mtlx2neural.textures.parameter_stack import build_parameter_stack
    from mtlx2neural.verify.energy import energy_check

    asset = Path(__file__).resolve().parents[2] / "samples" / "mirror" / "polished_metal.usda"
    src = find_material(asset, "/World/Looks/PolishedMetal")
    compiled = compile_material(src.document, src.material)
    cfg = preset("fast", seed=0, environment_fraction=0.0, preview_iterations=0)
    stack = build_parameter_stack(compiled, resolution=latent_resolution(compiled, cfg))
    ref = ReferenceMaterial(compiled)
    model = Trainer(ref, stack, cfg, tmp_path).run(progress=False)
    check = energy_check(ref, model, tuple(stack.resolution), len(model.latents.levels),
                         params_at=stack.native_params_at())
    assert check.min_ratio >= 0.94, [round(lv.ratio, 3) for lv in check.levels]


def test_an_interrupted_run_resumes_its_balance_bit_for_bit(carpaint, tmp_path, monkeypatch):
    """Interrupted after four updates and resumed, a balanced run ends with the weights of an uninterrupted one:
    the quantiles and their smoothing are in the checkpoint and apply from the next step on."""
    from mtlx2neural.train.trainer import TrainingInterrupted

    ref, stack = carpaint
    cfg = preset("fast", iterations=200, batch=64, seed=5, checkpoint_every=1000, environment_fraction=0.0,
                 preview_iterations=0)
    straight = Trainer(ref, stack, cfg, tmp_path / "a").run(progress=False).state_dict()
    tr = Trainer(ref, stack, cfg, tmp_path / "b")
    real_step = tr.train_step
    monkeypatch.setattr(tr, "train_step", lambda: (_ for _ in ()).throw(KeyboardInterrupt) if tr.step == 95
                        else real_step())
    with pytest.raises(TrainingInterrupted):
        tr.run(progress=False)
    again = Trainer(ref, stack, cfg, tmp_path / "b")
    assert again.resume() and again.step == 95 and again.balance is not None
    assert torch.equal(again.balance.taus, tr.balance.taus) and float(tr.balance.taus[0]) != 0.5
    resumed = again.run(progress=False).state_dict()
    assert all(torch.equal(straight[k], resumed[k]) for k in straight)
