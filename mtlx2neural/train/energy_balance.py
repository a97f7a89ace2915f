"""Energy balance: steer the BRDF loss's quantile per MIP level so each level keeps the reference's energy.

log-L1 follows the median of its targets (:mod:`mtlx2neural.train.losses`). A textured material's target
is the mean of a few footprint points, a right-skewed estimate where a footprint mixes a lobe's peak with
its surroundings, so with ``fast``'s 8 points the textured samples kept 85-93 % of their directional albedo;
32 points would keep it at twice the training time (docs/history/energy-levers-2026-12-06.md). The loss's
quantile ``tau`` moves the fit between the targets' median and their upper tail, and the quantile that
equals their mean depends on how skewed each level's targets are, so it is measured rather than set:

1. **Probe set**, drawn once from a generator of its own (seed ``cfg.seed + PROBE_SEED_OFFSET``, so the
   training's random numbers are untouched): per level, :data:`PROBE_TEXELS` texels, each seen from the
   energy check's four view angles, and the reference's directional albedo over each row's footprint
   (:func:`~mtlx2neural.textures.footprint_albedo.reference_footprint_albedo`, :data:`PROBE_POINTS` points of
   :data:`PROBE_SAMPLES` directions). The probe set is not the energy check's (seed 0), which stays a
   held-out measurement.
2. **Updates**, every :data:`EVERY_FRACTION` of the run from :data:`START_FRACTION` on (before that the model
   is too far from its targets for its energy to mean much): level k's ratio r_k = sum of the model's albedo
   luminance over the reference's (:func:`~mtlx2neural.textures.footprint_albedo.mixture_albedo`), smoothed
   in log space (:data:`SMOOTHING`), moves its quantile by ``-gain * log r_k`` (``cfg.energy_gain``), at most
   :data:`MAX_MOVE` per update, within [:data:`TAU_MIN`, :data:`TAU_MAX`].
3. **Calibration**, once, after the last step (:meth:`EnergyBalance.calibrate`, from ``Trainer.finish``): the run
   ends where the model's energy swings it, so the codes of each level under :data:`CALIBRATION_LOW` are shifted
   by one vector that brings the level's probe ratio up to it; the decoder is left as trained.

The training curves' ``loss_brdf`` is the loss each step minimised, so with quantiles other than 0.5 it is
not plain log-L1 (``held_out_log_l1`` in the summary is). A level that keeps its energy stays at its quantile,
so a material whose fit already conserves energy (a uniform plastic) trains as plain log-L1 would. The
model's energy swings between updates (the near mirror's by up to 2x between steps 50 apart, the coated
CarPaint's by 1.8x early in the run), which is why each move is bounded and smoothed and the first waits for
30 % of the run. The reference's albedo of the probe rows is estimated once, in :data:`PROBE_GROUPS` groups
with Sobol points of their own (:func:`_by_group`); the model's at each update in one call over every level.

Measured with ``fast``, seeds 0 / 1, lowest level ratio (docs/history/energy-balance-2026-12-07.md):
BrushedMetal 0.85 / 0.87 -> 0.99 / 1.01, GlazedCeramic 0.93 / 0.91 -> 0.99 / 0.97 (32 probe texels: 0.97 /
0.93), the CarPaint 0.96 / 0.99 -> 1.00 / 0.99; the near mirror 0.81-0.89 / 0.79 -> 0.95-0.97 / 0.79-0.92, one draw
from swings of tens of percent; the sphere views' HDR FLIP by 0-6 %, within the seeds' spread. With ``fast``'s
2000 steps of 1024 rows and 32 directions an update (0.15 s; 0.85 s at 128), the lowest level over every sample
and both seeds was 0.937-1.037 before the calibration: a level still swings by several percent between late
updates, and 64 texels read a textured level within about 2 % (docs/history/balance-cost-2026-12-07.md). With
it, 0.957-1.037, HDR FLIP as before within the seeds' spread (docs/history/energy-calibration-2026-12-07.md). A UDIM
material is not balanced (its levels are per tile), as the energy check does not measure it.
"""

from __future__ import annotations

import math

import torch

from mtlx2neural.reference.vec import luminance
from mtlx2neural.textures.footprint_albedo import (
    model_level_albedo,
    probe_rows,
    reference_footprint_albedo,
)

MIN_ITERATIONS = 200
"""Runs shorter than this are not balanced: their model's energy is too far from settled to steer by."""
START_FRACTION = 0.3
"""Share of the run before the first update."""
EVERY_FRACTION = 0.05
"""Share of the run between updates (100 steps of ``fast``'s 2000)."""
PROBE_TEXELS = 64
"""Texels per level in the probe set (each seen from four view angles)."""
PROBE_POINTS = 4
"""Footprint points per probe row for the reference's albedo."""
PROBE_SAMPLES = 32
"""Directions per footprint point of the reference's albedo (drawn once)."""
MODEL_SAMPLES = 32
"""Directions per probe row of the model's albedo at each update."""
PROBE_GROUPS = 8
"""Groups of probe rows with Sobol points of their own (:func:`_by_group`)."""
PROBE_VIEWS = (0.0, 30.0, 60.0, 80.0)
"""View angles from the normal, degrees (the energy check's)."""
PROBE_SEED_OFFSET = 7919
"""The probe set's generator is seeded with the run's seed plus this."""
SMOOTHING = 0.5
"""Weight of the previous smoothed log ratio in each update (exponential smoothing)."""
MAX_MOVE = 0.05
"""Largest change of a level's quantile in one update."""
TAU_MIN, TAU_MAX = 0.3, 0.8
"""The quantile's bounds."""
CALIBRATION_STEPS = 2
"""Gauss-Newton steps of :meth:`EnergyBalance.calibrate` (the second brings every level of the near mirror's
probe set from within 1 % to within 0.1 % of 1)."""
CALIBRATION_LOW, CALIBRATION_HIGH = 1.0, math.inf
"""The band a level's probe ratio is calibrated into: a level under 1 is raised to 1, one over it left as trained.
No upper edge: a level's ratio averages four view angles, and its excess sits at the grazing ones (the
GlazedCeramic's level 0: 0.97 at 0-60 degrees, 1.08 at 80), so lowering it darkens the views an image shows most.
An edge at 1.1 raised the near mirror's in-scene HDR FLIP 0.147 -> 0.154 (seed 1) and the scene sample's gold
plate's 0.135 -> 0.18-0.20 (``--network scene --encoder universal``, seeds 0 and 1), its sphere views unchanged
(docs/history/energy-calibration-2026-12-08.md)."""
CALIBRATION_MAX_SHIFT = 0.25
"""The largest shift of a level's codes in one calibration step, as a share of the norm of its typical code (the
root mean square over its texels and channels, times the square root of the channels): a level whose energy
hardly depends on its codes is not pushed far off its trained codes (the near mirror's shifts were 1-3 % of it).
A level the steps did not bring half way to the band gets its trained codes back."""
CALIBRATION_MAX_LOG = 0.2
"""Largest |log ratio| one calibration step corrects (a level further off than 22 % moves that far and no
further: the energy check then reports it)."""


def _by_group(rows: int, albedo) -> torch.Tensor:
    """``albedo(rows [m], group j) -> [m, 3]`` over ``rows`` probe rows split into :data:`PROBE_GROUPS` groups,
    concatenated in row order: each group draws Sobol points of its own seed, so rows of one view angle do not
    share their error (one sequence for every row gave one CarPaint model 0.91-0.99 across probe seeds). Used for
    the reference's albedo, drawn once; the model's estimate shifts its points per row instead
    (:func:`~mtlx2neural.textures.footprint_albedo.row_shifted_sobol`)."""
    return torch.cat([albedo(idx, j) for j, idx in enumerate(torch.arange(rows).chunk(PROBE_GROUPS))])


def _band_excess(log_r: torch.Tensor) -> torch.Tensor:
    """How far each log ratio lies outside [log :data:`CALIBRATION_LOW`, log :data:`CALIBRATION_HIGH`] (0 inside)."""
    return log_r - log_r.clamp(math.log(CALIBRATION_LOW), math.log(CALIBRATION_HIGH))


def update_due(step: int, iterations: int) -> bool:
    """Whether an update falls after step ``step`` (counted from 1) of a run of ``iterations``: from
    :data:`START_FRACTION` of the run on, every :data:`EVERY_FRACTION` of it, never after the last step (no
    step would follow it); never in a run shorter than :data:`MIN_ITERATIONS`."""
    if iterations < MIN_ITERATIONS:
        return False
    start = max(1, round(START_FRACTION * iterations))
    every = max(1, round(EVERY_FRACTION * iterations))
    return start <= step < iterations and (step - start) % every == 0


class EnergyBalance:
    """Per-level quantiles of a training run's BRDF loss, steered by the energy the model keeps (module
    docstring). ``reference`` and ``levels`` / ``resolution`` (the latent pyramid's level count and finest
    grid, H x W texels) are the run's; ``params_at`` and ``coverage`` as the energy check takes them;
    ``gain``: ``cfg.energy_gain``; ``seed``: the run's (the probe set's generator and Sobol seed derive from
    it). :func:`update_due` says when to call :meth:`update`."""

    def __init__(self, reference, levels: int, resolution: tuple[int, int], *, gain: float, seed: int,
                 params_at=None, coverage=None, device="cpu"):
        self.reference, self.params_at, self.device = reference, params_at, device
        self.gain = float(gain)
        self.taus = torch.full((levels,), 0.5)
        self.smoothed: torch.Tensor | None = None
        self.seed = seed
        g = torch.Generator().manual_seed(seed + PROBE_SEED_OFFSET)
        self.rows = []  # per level: (uv [n, 2], wi [n, 3], summed luminance of the reference's albedo)
        for k in range(levels):
            uv, wi, _ = probe_rows(PROBE_TEXELS, PROBE_VIEWS, g, coverage)
            ref = _by_group(wi.shape[0], lambda idx, j, uv=uv, wi=wi, k=k: reference_footprint_albedo(
                reference, wi[idx], uv[idx], k, resolution, points=PROBE_POINTS, samples=PROBE_SAMPLES, seed=seed + j,
                generator=g, params_at=params_at, coverage=coverage, device=device))
            self.rows.append((uv, wi, float(luminance(ref.float().cpu()).sum())))

    def ratios(self, model, grad: bool = False) -> torch.Tensor:
        """[levels] the model's energy ratio per level on the probe set (model / reference albedo luminance),
        from :data:`MODEL_SAMPLES` directions per row. Every level's rows go in one call, each row at its own
        level with Sobol points shifted by a vector of its own
        (:func:`~mtlx2neural.textures.footprint_albedo.row_shifted_sobol`), so a level's sum averages its rows'
        errors. ``grad``: the ratios keep their graph to the model's BRDF values (the directions held fixed)."""
        uv = torch.cat([r[0] for r in self.rows])
        wi = torch.cat([r[1] for r in self.rows])
        level = torch.cat([torch.full((r[1].shape[0],), k) for k, r in enumerate(self.rows)])
        mod = model_level_albedo(model, self.reference, wi, uv, level, samples=MODEL_SAMPLES, seed=self.seed,
                                 params_at=self.params_at, device=self.device, grad=grad)
        sums = torch.zeros(len(self.rows)).index_add(0, level, luminance(mod.float().cpu()))
        refs = torch.tensor([r[2] for r in self.rows])
        return torch.where(refs > 0, sums / refs.clamp_min(1e-30), torch.ones_like(sums))

    def calibrate(self, model, steps: int = CALIBRATION_STEPS) -> tuple[list[float], list[float]]:
        """The balance's last step, after the run's: shift every latent code of MIP level k by one vector
        d_k so that the level's ratio on the probe set comes into [:data:`CALIBRATION_LOW`,
        :data:`CALIBRATION_HIGH`] (no upper edge: only a level under 1 moves); returns the probe's ratios before
        and after.

        d_k is a Gauss-Newton step on e_k = log r_k - log clamp(r_k, low, high): with g_k the gradient of
        log r_k with respect to a common shift of the level's codes (the sum of its per-texel gradients),
        d_k = -e_k g_k / |g_k|^2, the smallest shift that moves e_k to 0 to first order;
        :data:`CALIBRATION_STEPS` of them (the quadrature's directions drawn again from the shifted model,
        :data:`CALIBRATION_MAX_LOG` and :data:`CALIBRATION_MAX_SHIFT` at most each); a level they did not bring
        half way to the band gets its trained codes back. A shift of the codes is what a level's texture can carry:
        the decoder, shared by every level and every texel, stays as trained.

        Why only upwards: a level's ratio averages four view angles, and a level over 1 is mostly one too
        bright at grazing views (the GlazedCeramic's level 0: 0.97 at 0-60 degrees, 1.08-1.13 at 80); shifting it
        to 1 darkened its other views, and its HDR FLIP rose 10 %; to 1.1 cost in-scene figures
        (:data:`CALIBRATION_HIGH`). Under 1 is the issue this corrects (a level that lost energy: a dark near
        mirror, a lost highlight). Measured on ``fast`` (docs/history/energy-calibration-2026-12-07.md, -12-08.md)."""
        levels = list(model.latents.levels)
        trained = [lv.detach().clone() for lv in levels]
        # the largest shift a level takes in one step: CALIBRATION_MAX_SHIFT of the norm of its typical code
        caps = [CALIBRATION_MAX_SHIFT * float(lv.detach().square().mean().sqrt()) * lv.shape[-3] ** 0.5
                for lv in levels]
        before, moved = None, False
        for _ in range(steps):
            ratios = self.ratios(model, grad=True)
            log_r = torch.log(ratios.clamp_min(1e-6))
            excess = _band_excess(log_r.detach())
            before = ratios.detach() if before is None else before
            if not bool((excess != 0).any()):
                break
            moved = True
            grads = torch.autograd.grad(log_r.sum(), levels, allow_unused=True)
            with torch.no_grad():
                for lv, g, e, cap in zip(levels, grads, excess, caps):
                    if g is None or float(e) == 0.0:  # inside the band, or a level the probe did not read
                        continue
                    d = g.sum(dim=(-2, -1))  # d log r_k / d(a shift of every code of level k), [channels]
                    shift = -e.clamp(-CALIBRATION_MAX_LOG, CALIBRATION_MAX_LOG) * d / (d @ d).clamp_min(1e-20)
                    shift = shift * min(1.0, cap / max(float(shift.norm()), 1e-30))
                    lv.add_(shift[:, None, None].to(lv.dtype))
        if before is None:  # no steps
            before = self.ratios(model)
        if not moved:
            return before.tolist(), before.tolist()
        after = self.ratios(model)
        start = _band_excess(torch.log(before.clamp_min(1e-6))).abs()
        worse = _band_excess(torch.log(after.clamp_min(1e-6))).abs() > 0.5 * start + 1e-6
        if bool(worse.any()):  # a level the steps did not bring half way to the band goes back
            with torch.no_grad():
                for lv, old, back in zip(levels, trained, worse.tolist()):
                    if back:
                        lv.copy_(old)
            after = self.ratios(model)
        return before.tolist(), after.tolist()

    def update(self, model) -> list[float]:
        """Measure the model's ratios and move each level's quantile (module docstring); returns the ratios."""
        ratios = self.ratios(model)
        log_r = torch.log(ratios.clamp(0.2, 5.0))
        log_r = torch.where(torch.isfinite(log_r), log_r, torch.zeros_like(log_r))
        self.smoothed = log_r if self.smoothed is None else SMOOTHING * self.smoothed + (1 - SMOOTHING) * log_r
        move = (-self.gain * self.smoothed).clamp(-MAX_MOVE, MAX_MOVE)
        self.taus = (self.taus + move).clamp(TAU_MIN, TAU_MAX)
        return ratios.tolist()

    def row_tau(self, level: torch.Tensor) -> torch.Tensor:
        """[N] each row's quantile, from its MIP level [N] (int64)."""
        return self.taus.to(level.device)[level]

    def state_dict(self) -> dict:
        """What a checkpoint keeps of the balance (the probe set is redrawn from the seed)."""
        return {"taus": self.taus.tolist(), "smoothed": None if self.smoothed is None else self.smoothed.tolist()}

    def load_state_dict(self, state: dict | None) -> None:
        """Restore :meth:`state_dict`'s values (None: a checkpoint written without a balance)."""
        if not state:
            return
        self.taus = torch.tensor(state["taus"], dtype=torch.float32)
        self.smoothed = None if state.get("smoothed") is None else torch.tensor(state["smoothed"])
