"""Train a neural material against its reference (docs/ARCHITECTURE.md, "model" and "train").

Three phases over ``cfg.iterations`` steps:
1. encoder end to end: prefiltered parameters at (uv, level) -> encoder -> decoder;
2. bake: the encoder runs over every texel of every level of the parameter pyramid;
3. fine-tune: the baked latents are optimised directly (with the decoder and sampler).

Each step draws (uv, level, wi, wo) (a share of wo near the reference's lobes and,
with ``grazing_fraction``, extra rows with wi near the horizon), a footprint-filtered
and mollified reference target (the cone narrows with the paper's cosine decay, then stays
at a floor; ``train.mollify``), and optimises the log-L1 BRDF loss (its quantile per MIP level steered
by the energy the model keeps, with ``energy_gain``: ``train.energy_balance``) plus the sampler's KL loss
against the current neural BRDF, scored on the sampler's own samples mixed with cosine ones
(latents detached; docs/history/paper-choices-2026-12-02.md), plus the albedo head's loss when it
has one (every loss: ``train.losses``). With ``environment_fraction``, the environment head is fitted
last, the rest frozen (``train.environment_fit``).
Adam(0.9, 0.999, 1e-7) with a cosine learning-rate decay. Progress shows phase,
loss and ETA; checkpoints are written atomically and on Ctrl-C; curves go to a CSV.

What differs between a uniform, a textured and a UDIM material lives outside the trainer, chosen
once from the parameter stack: the targets and MIP levels of the rows (``train.targets``) and the
latents' grid and bake (``train.latent_init``).
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import math
import time
from pathlib import Path

import torch

from mtlx2neural.atomic import atomic_path
from mtlx2neural.errors import InputError
from mtlx2neural.formats.latent_codec import check_block_shapes
from mtlx2neural.model.neural_material import NeuralMaterial
from mtlx2neural.progress import progress_bar
from mtlx2neural.textures.parameter_stack import ParameterStack
from mtlx2neural.textures.surface_maps import SurfaceMaps, dilate
from mtlx2neural.train.adam import Adam, cosine_lr
from mtlx2neural.train.config import TrainConfig
from mtlx2neural.train.directions import grazing_directions, half_difference_pairs
from mtlx2neural.train.encoder_input import EncoderInput
from mtlx2neural.train.energy_balance import MIN_ITERATIONS, EnergyBalance, update_due
from mtlx2neural.train.environment_fit import fit_environment_head
from mtlx2neural.train.grad_clip import SpikeClip
from mtlx2neural.train.latent_init import (
    freeze_encoder,
    is_textured,
    latent_init_for,
    noise_latents,
)
from mtlx2neural.train.losses import (
    albedo_loss,
    brdf_and_sampler_losses,
    brdf_loss_of,
    raw_floor,
)
from mtlx2neural.train.mollify import lobe_directions
from mtlx2neural.train.replay import RowReplay
from mtlx2neural.train.targets import targets_for
from mtlx2neural.train.udim import draw_uv, is_udim_stack

GRAZING_MAX_COS = 0.25  # cfg.grazing_fraction's viewers: within ~14 degrees of the horizon
SURFACE_REDRAWS = 8  # rounds of redrawing uv that fell where a cut-out has no surface
GRAZING_LOBE_SHARE = 0.5  # share of the grazing rows whose wo is redrawn near a lobe (with lobe_fraction > 0)


@dataclasses.dataclass
class StepRows:
    """One step's batch (:meth:`Trainer.step_rows`): the rows of :meth:`Trainer.draw_rows` (``uv``, ``level``,
    ``wi``, ``wo``, ``target``), their latent codes ``latent`` [N, latent_dim] (with the graph to the encoder
    or the latent pyramid), the sampler loss's uniform numbers ``u_kl`` [N, 3], each row's BRDF loss
    quantile ``tau`` [N] (None without an energy balance: plain log-L1) and whether the BRDF loss may lift
    (``lift``: in the first ``lift_fraction`` of the run; :mod:`.losses`)."""

    uv: torch.Tensor
    level: torch.Tensor
    wi: torch.Tensor
    wo: torch.Tensor
    target: torch.Tensor
    latent: torch.Tensor
    u_kl: torch.Tensor
    tau: torch.Tensor | None = None
    lift: bool = False


class TrainingInterrupted(Exception):
    """Raised after Ctrl-C once a checkpoint has been written."""


def balanced(cfg: TrainConfig, tiles) -> bool:
    """Whether a run of ``cfg`` balances its energy (:mod:`.energy_balance`): not without ``energy_gain``, not
    for a UDIM material (``tiles``: its levels are per tile) and not with relative_l2 (which seeks the mean
    already)."""
    return cfg.energy_gain > 0 and tiles is None and cfg.brdf_loss != "relative_l2"


def _lr(cfg: TrainConfig, step: int) -> float:
    return cosine_lr(cfg.lr_start, cfg.lr_end, step, cfg.iterations)


def lifts(cfg: TrainConfig, step: int) -> bool:
    """Whether step ``step`` (counted from 0) may lift the BRDF loss (:mod:`.losses`; it does where the batch's fit is
    dead): in the first ``cfg.lift_fraction`` of the run."""
    return step < round(cfg.lift_fraction * cfg.iterations)


def mollify_angle_at(cfg: TrainConfig, step: int) -> float:
    """The mollification cone half-angle (radians) of ``step`` of ``cfg``'s schedule
    (:meth:`Trainer.mollify_angle`)."""
    t = min(1.0, step / max(1.0, cfg.iterations * cfg.mollify_fraction))
    decay = 0.5 * (1.0 + math.cos(math.pi * t))
    return math.radians(max(cfg.mollify_degrees * decay, cfg.mollify_min_degrees))


def at_mollify_floor(cfg: TrainConfig, step: int) -> bool:
    """Whether ``step``'s mollification angle is at its floor (``mollify_min_degrees``), where it then stays."""
    return mollify_angle_at(cfg, step) <= math.radians(cfg.mollify_min_degrees)


def _atomic_save(obj, path: Path) -> None:
    with atomic_path(path) as tmp:
        torch.save(obj, tmp)


class Trainer:
    """One material's training run: the model, the optimiser, the step loop, checkpoints and curves
    (module docstring). ``stack`` is the material's parameter stack (a UDIM ``TiledStack`` for a UDIM
    material); ``device`` where the model and batches live (random numbers are drawn on the CPU)."""

    def __init__(self, reference, stack: ParameterStack, cfg: TrainConfig, out_dir: Path, device="cpu",
                 surface: SurfaceMaps | None = None):
        self.ref, self.stack, self.cfg = reference, stack, cfg
        # A cut-out's coverage (textures.surface_maps): rows are drawn where there is surface, footprints
        # weighted by it, and empty texels' latents dilated from their neighbours after training.
        self.surface = surface if surface is not None and surface.partial and not is_udim_stack(stack) else None
        self.out_dir = Path(out_dir)
        self.device = torch.device(device)
        self.textured = is_textured(stack)
        # A UDIM material (train.udim.TiledStack): one latent pyramid per trained tile, uv drawn over them.
        self.tiles = list(stack.tiles) if is_udim_stack(stack) else None
        self.latent_init = latent_init_for(stack)  # the latents' grid and bake for this kind of material
        torch.manual_seed(cfg.seed)  # the model's initial weights
        self.encoder_input = EncoderInput(stack, cfg.encoder_input)  # what the encoder reads of a texel
        self.model = NeuralMaterial(self.latent_init.resolution, self.encoder_input.dim,
                                    cfg.latent_dim, cfg.frames, cfg.decoder, cfg.albedo_head,
                                    cfg.analytic_cosine, tiles=self.tiles,
                                    latent_format=cfg.latent_format,
                                    environment_head=cfg.environment_steps > 0).to(self.device)
        if cfg.latent_format != "exr":  # DDS MIP chains halve rounding down: refuse other grids before training
            try:
                check_block_shapes([tuple(lv.shape[-2:]) for lv in self.model.latents.levels])
            except ValueError as exc:
                raise InputError(f"--latent-format {cfg.latent_format}: {exc}") from None
        self.opt = Adam(self.model.parameters(), lr=cfg.lr_start, betas=(0.9, 0.999), eps=1e-7)
        self.step = 0
        self.baked = False
        self.history: list[dict] = []
        self.clipped_steps = 0
        self.clip = SpikeClip()  # the gradient-norm spike guard (train.grad_clip)
        self.environment_history: list[dict] = []  # the environment head's fit, once the BRDF is trained
        self.gen = torch.Generator().manual_seed(cfg.seed)  # every random draw of the training data
        self.targets = targets_for(reference, stack, cfg, self.gen,  # the rows' levels and targets for this kind
                                   self.surface.coverage_at if self.surface is not None else None)
        self.replay = RowReplay(cfg.batch, cfg.target_reuse, cfg.target_prefetch)
        # torch.compile fuses the MLPs' bias/ReLU/elementwise chains (BENCHMARKS.md, "Training throughput"); it costs
        # tens of seconds of compilation, so only the long presets turn it on.
        if cfg.compile:
            import logging

            torch._logging.set_logs(dynamo=logging.ERROR)  # the reference's data-dependent branches break graphs
        losses = functools.partial(brdf_and_sampler_losses, brdf_loss=brdf_loss_of(cfg.brdf_loss, cfg.brdf_eps),
                                   floor=raw_floor(cfg.brdf_floor))
        self._losses = torch.compile(losses) if cfg.compile else losses
        self.balance: EnergyBalance | None = None  # built at its first update (:meth:`balance_energy`)
        # Whether the run ends with the energy calibration (:meth:`calibrate_energy`): fixed by the config the
        # trainer is built with, so a fine-tune that turns the balance's updates off (universal.fit) keeps it.
        self.calibrates = balanced(cfg, self.tiles)
        self._balance_state = None  # a resumed run's balance, restored when it is built
        if cfg.encoder_fraction <= 0:
            self._direct_latents()

    # -- checkpoints -------------------------------------------------------------------
    @property
    def checkpoint_path(self) -> Path:
        return self.out_dir / "checkpoint.pt"

    def save(self) -> None:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        _atomic_save({"model": self.model.state_dict(), "opt": self.opt.state_dict(), "step": self.step,
                      "baked": self.baked, "history": self.history, "config": dataclasses.asdict(self.cfg),
                      "rng": self.gen.get_state(), "udim_tiles": self.tiles,
                      "replay": self.replay.state_dict(), "environment_history": self.environment_history,
                      "energy_balance": self.balance.state_dict() if self.balance is not None else self._balance_state},
                     self.checkpoint_path)
        self._write_curves()

    def resume(self) -> bool:
        if not self.checkpoint_path.exists():
            return False
        ck = torch.load(self.checkpoint_path, map_location=self.device, weights_only=False)
        self.model.load_state_dict(ck["model"])
        self.opt.load_state_dict(ck["opt"])
        self.step, self.baked, self.history = ck["step"], ck["baked"], ck["history"]
        self.clipped_steps = self.history[-1].get("clipped_steps", 0) if self.history else 0
        self.gen.set_state(ck["rng"])
        self.replay.load_state_dict(ck.get("replay"), self.device)
        self.environment_history = ck.get("environment_history", [])
        self._balance_state = ck.get("energy_balance")
        if self._balance_state:  # the quantiles the run had reached apply from its next step
            self._build_balance()
        return True

    def _write_curves(self) -> None:
        if not self.history:
            return
        fields = list(dict.fromkeys(k for rec in self.history for k in rec))  # a resumed older run lacks some
        with atomic_path(self.out_dir / "training_curves.csv") as tmp, open(tmp, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=fields)
            w.writeheader()
            w.writerows(self.history)

    # -- one step ----------------------------------------------------------------------
    def mollify_angle(self) -> float:
        """This step's mollification cone half-angle (radians): the paper's cosine decay (supplement,
        eq. 2) from ``mollify_degrees`` to 0 over ``mollify_fraction`` of the run,
        ``0.5 * mollify_degrees * (1 + cos(pi * t))`` with t the share of that span done, never below
        ``mollify_min_degrees``. (The linear schedule it replaced, and the measurement, are in
        docs/history/paper-choices-2026-12-02.md.)"""
        return mollify_angle_at(self.cfg, self.step)

    def _targets(self, wi, wo, uv, level):
        """[N, 3] this step's targets (f * cos, linear RGB) at the rows: the material kind's
        (``train.targets``) at the current mollification angle."""
        return self.targets.brdf(wi, wo, uv, level, self.mollify_angle())

    def albedo_targets(self, wi: torch.Tensor, uv: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
        """One-sample Monte Carlo estimates [N,3] of the reference's directional albedo (f * cos integrated
        over wo, linear RGB) at each row's point: the reference's sample weight at ``wi`` (local frame).

        A textured material is sampled at a point of the row's footprint (``uv`` plus a Gaussian offset of
        the level's standard deviation), so the estimate's mean is the albedo averaged over the
        footprint, as the BRDF targets are; a uniform material ignores ``uv`` and ``level``
        (``train.targets``)."""
        return self.targets.albedo(wi, uv, level)

    def _latent(self, uv, level):
        if self.baked:
            return self.model.latents.fetch(uv, level)
        return self.model.encoder(self.encoder_input(self.stack.sample_raw(uv, level)))

    def _direct_latents(self) -> None:
        """No encoder phase (the ablation's "vanilla" model): latents start as small Gaussian
        noise (std 0.1, seeded with ``seed + 1``) and are optimised directly from the first step."""
        noise_latents(self.model, self.cfg.seed + 1)
        self.baked = True
        freeze_encoder(self.model)

    def bake(self) -> None:
        """Phase 2: run the encoder over every texel of every level into the latent pyramid (and, for a
        block-compressed ``latent_format``, the last ``block_fraction`` of the steps read them through
        the block decoder's emulation: :meth:`_block_phase`)."""
        self._encode_latents()
        self.baked = True
        # The encoder is no longer used: keep optimising latents, decoder and sampler.
        freeze_encoder(self.model)

    def _encode_latents(self) -> None:
        """The encoder over every texel of every level, into the latent pyramid (no flag changes: before
        the bake, the latents are not trained on, so a probe may fill them early)."""
        self.latent_init.encode(self.model, self.encoder_input)

    def surface_uv(self, n: int) -> torch.Tensor:
        """[n, 2] uv drawn over the material (over its UDIM tiles), on the CPU from the training's generator; those
        that land where a cut-out has no surface are drawn again (up to :data:`SURFACE_REDRAWS` rounds), so rows
        train the surface that is there: the empty texels' latents are dilated copies of their neighbours'."""
        uv = draw_uv(n, self.tiles, self.gen)
        if self.surface is not None:
            for _ in range(SURFACE_REDRAWS):
                empty = torch.nonzero(~self.surface.texel_covered(uv))[:, 0]
                if len(empty) == 0:
                    break
                uv[empty] = draw_uv(len(empty), self.tiles, self.gen)
        return uv

    def draw_rows(self, batch: int) -> tuple[torch.Tensor, ...]:
        """Fresh training rows for a BRDF batch of ``batch``: ``(uv, level, wi, wo, target)`` with
        ``batch`` plus ``grazing_fraction * batch`` rows (uv in [0,1]^2, or over the UDIM tiles; level a
        pyramid index; wi/wo unit vectors in the local shading frame, z-up; target [N,3] the
        footprint-filtered, mollified reference BRDF f * cos, the cosine included, linear RGB)."""
        cfg, g, dev = self.cfg, self.gen, self.device
        n_graze = round(cfg.grazing_fraction * batch)
        b = batch + n_graze
        uv = self.surface_uv(b).to(dev)
        level = self.targets.levels(b, dev)
        wi, wo = half_difference_pairs(b, g, dev)
        if n_graze > 0:  # extra rows whose viewer is near the horizon (their wo stays as drawn, above it)
            wi = torch.cat([wi[:batch], grazing_directions(n_graze, GRAZING_MAX_COS, g, dev)])
        # Rows whose wo is redrawn near the reference's lobes (uv, levels and wi are random already):
        # the first of the batch, and a share of the grazing rows (the coat's spike at a low viewer).
        n_lobe = round(cfg.lobe_fraction * batch)
        n_graze_lobe = round(GRAZING_LOBE_SHARE * n_graze) if n_lobe else 0
        rows = torch.cat([torch.arange(n_lobe, device=dev), batch + torch.arange(n_graze_lobe, device=dev)])
        if len(rows) > 0:
            with torch.no_grad():
                ws, ok = lobe_directions(self.ref, wi[rows], self.mollify_angle(), g, self.targets.lobe_uv(uv[rows]))
            wo = wo.index_copy(0, rows, torch.where(ok[:, None], ws, wo[rows]))
        with torch.no_grad():
            target = self._targets(wi, wo, uv, level)
        return uv, level, wi, wo, target

    @property
    def block_start(self) -> int:
        """The first step that reads the latents through the block decoder's emulation: the last
        ``block_fraction`` of the run, never before the bake."""
        cfg = self.cfg
        return max(int(cfg.iterations * cfg.encoder_fraction), cfg.iterations - round(cfg.block_fraction * cfg.iterations))

    def _block_phase(self) -> None:
        """Read the latents uncompressed before :attr:`block_start`, through the codec from then on; at that
        step (once per run, resumed or not: its fit is in the state dict) fit the codec's range to them."""
        lat = self.model.latents
        if lat.codec is None:
            return
        if self.step == self.block_start:
            lat.codec.fit(list(lat.levels))
        lat.codec_active = self.step >= self.block_start

    def dilate_empty_texels(self) -> None:
        """Fill the latents of every texel without surface (a cut-out's empty part, level by level) from
        their covered neighbours (:func:`~mtlx2neural.textures.surface_maps.dilate`), so a bilinear or
        coarser lookup at an edge mixes in codes like the surface's own."""
        if self.surface is None:
            return
        with torch.no_grad():
            for lv, cov in zip(self.model.latents.levels, self.surface.coverage_levels):
                if tuple(lv.shape[-2:]) == tuple(cov.shape):
                    lv.copy_(dilate(lv.detach(), cov.to(lv.device) > 0))

    def step_loss(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One batch's training loss (``(total, brdf, kl)``, scalars with graphs): fresh or replayed rows,
        the BRDF and sampler losses, and the albedo head's when it has one. No optimiser step."""
        rows = self.step_rows()
        loss_brdf, loss_kl = self._losses(self.model.decoder, self.model.sampler, rows.latent, rows.wi, rows.wo,
                                          rows.target, rows.u_kl, tau=rows.tau, lift=rows.lift)
        loss = loss_brdf + loss_kl
        if self.cfg.albedo_head:
            loss = loss + self.albedo_term(rows)
        return loss, loss_brdf, loss_kl

    def step_rows(self) -> StepRows:
        """This step's rows (fresh or replayed) and their latents, before any loss (:meth:`step_loss`)."""
        self._block_phase()
        uv, level, wi, wo, target = self.replay.batch(self.draw_rows)
        latent = self._latent(uv, level)
        u_kl = torch.rand(wi.shape[0], 3, generator=self.gen).to(self.device)
        tau = self.balance.row_tau(level) if self.balance is not None else None
        return StepRows(uv, level, wi, wo, target, latent, u_kl, tau, lifts(self.cfg, self.step))

    def albedo_term(self, rows: StepRows) -> torch.Tensor:
        """The albedo head's loss on ``rows`` (its targets drawn now, from the reference)."""
        with torch.no_grad():
            weight = self.albedo_targets(rows.wi, rows.uv, rows.level)
        return albedo_loss(self.model.decoder.predict_albedo(rows.latent, rows.wi), weight)

    def step_record(self, loss_brdf, loss_kl, grad_norm: float) -> dict:
        """The curves' record of the step just taken."""
        return {"step": self.step, "phase": "finetune" if self.baked else "encoder",
                "loss_brdf": loss_brdf.item(), "loss_kl": loss_kl.item(), "lr": _lr(self.cfg, self.step),
                "grad_norm": grad_norm, "clipped_steps": self.clipped_steps}

    def _build_balance(self) -> None:
        """The energy balance (:mod:`.energy_balance`), built once, with a resumed run's state."""
        if self.balance is not None:
            return
        self.balance = EnergyBalance(
            self.ref, len(self.model.latents.levels), tuple(self.stack.resolution), gain=self.cfg.energy_gain,
            seed=self.cfg.seed, device=self.device, params_at=self.stack.native_params_at(),
            coverage=self.surface.coverage_at if self.surface is not None else None)
        self.balance.load_state_dict(self._balance_state)

    def balance_energy(self) -> dict:
        """After a step: update the energy balance's quantiles when an update is due
        (:mod:`.energy_balance`), building the balance at its first; returns the curves' fields of the update
        (``energy_ratio_min``, ``energy_tau_min``, ``energy_tau_max``), empty when there was none. No balance
        without ``cfg.energy_gain``, for a UDIM material (its levels are per tile) or with relative_l2 (which
        seeks the mean already). The probe fills the latents from the encoder before the bake, as a FLIP
        probe does."""
        cfg = self.cfg
        if not balanced(cfg, self.tiles) or not update_due(self.step, cfg.iterations):
            return {}
        self._build_balance()
        if not self.baked:
            self._encode_latents()
        ratios = self.balance.update(self.model)
        taus = self.balance.taus
        return {"energy_ratio_min": round(min(ratios), 4), "energy_tau_min": round(float(taus.min()), 4),
                "energy_tau_max": round(float(taus.max()), 4)}

    def train_step(self) -> dict:
        loss, loss_brdf, loss_kl = self.step_loss()
        for group in self.opt.param_groups:
            group["lr"] = _lr(self.cfg, self.step)
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        # A spike far above the run's recent gradient norms is clipped (train.grad_clip); the curves count them.
        grad_norm, clipped = self.clip(self.model.parameters())
        self.clipped_steps += clipped
        self.opt.step()
        self.step += 1
        return self.step_record(loss_brdf, loss_kl, grad_norm)

    def finish(self, calibrate: bool = True) -> None:
        """After the last step: bake (if the run never reached it), calibrate each level's energy
        (:meth:`calibrate_energy`; ``calibrate`` False: the caller does it after steps of its own), fill a
        cut-out's empty texels, and put a block-compressed pyramid through its codec, as it ships."""
        if not self.baked:
            self.bake()
        if calibrate:
            self.calibrate_energy()
        self.dilate_empty_texels()
        if self.model.latents.codec is not None:  # what ships: the latents through the codec
            if self.step <= self.block_start:  # never trained through it (block_fraction 0, or no steps)
                self.model.latents.codec.fit(list(self.model.latents.levels))
            self.model.latents.codec_active = True

    def calibrate_energy(self) -> None:
        """When the trainer's config balances the energy (:attr:`calibrates`, set when it was built), shift each
        MIP level's codes into the balance's band (:meth:`.EnergyBalance.calibrate`; the balance is built here
        when no update built it: a fine-tune without updates); the curves' last record gets the lowest probe
        ratio before (``energy_calibrated_from``) and after (``energy_ratio_min``). A run shorter than
        :data:`.energy_balance.MIN_ITERATIONS` is not calibrated, as it is not balanced."""
        if not self.calibrates or self.cfg.iterations < MIN_ITERATIONS:
            return
        self._build_balance()
        before, after = self.balance.calibrate(self.model)
        if self.history and self.history[-1].get("step") == self.step:
            self.history[-1].update(energy_calibrated_from=round(min(before), 4), energy_ratio_min=round(min(after), 4))

    def fit_environment(self) -> None:
        """Fit the environment head (``cfg.environment_steps`` steps, :mod:`.environment_fit`) once the
        BRDF is trained; nothing when the config has none or a resumed run already fitted it."""
        cfg = self.cfg
        if cfg.environment_steps <= 0 or self.environment_history:
            return
        t = time.time()
        self.environment_history = fit_environment_head(self, cfg.environment_steps, cfg.environment_batch)
        self.model.zero_grad(set_to_none=True)
        self.environment_history[-1]["seconds"] = round(time.time() - t, 2)

    def run(self, progress: bool = True, listener=None, probe=None) -> NeuralMaterial:
        """Train to ``cfg.iterations`` steps (from the current step), showing progress when
        ``progress`` (a bar on a terminal, periodic log lines otherwise: :mod:`mtlx2neural.progress`); ``listener(step, total, record)`` is called with every logged record
        (every 25 steps), e.g. to draw a parent process's bar for a pool worker.

        ``probe(model) -> float`` (e.g. :class:`~mtlx2neural.render.flip_probe.FlipProbe`): called every
        ``cfg.probe_every`` steps and at the last one, its value logged as ``flip_probe`` (NaN in the other
        records); before the bake the latents are filled from the encoder for it. Its time is not counted
        in ``seconds`` (training seconds)."""
        cfg = self.cfg
        switch = int(cfg.iterations * cfg.encoder_fraction)
        bar = progress_bar(cfg.iterations, self.step, enabled=progress, desc=self.out_dir.name)
        start, probing = time.time(), 0.0
        try:
            while self.step < cfg.iterations:
                if not self.baked and self.step >= switch:
                    self.bake()
                rec = self.train_step()
                if not all(math.isfinite(rec[k]) for k in ("loss_brdf", "loss_kl", "grad_norm")):
                    raise FloatingPointError(f"non-finite loss at step {self.step}: {rec}")
                balanced = self.balance_energy()
                rec.update(balanced)
                rec["flip_probe"] = math.nan
                if probe is not None and cfg.probe_every > 0 and (self.step % cfg.probe_every == 0
                                                                  or self.step == cfg.iterations):
                    t = time.time()
                    if not self.baked:
                        self._encode_latents()
                    rec["flip_probe"] = round(float(probe(self.model)), 5)
                    probing += time.time() - t
                if (self.step % 25 == 0 or self.step == cfg.iterations or math.isfinite(rec["flip_probe"])
                        or balanced):
                    rec["seconds"] = round(time.time() - start - probing, 2)
                    self.history.append(rec)
                    bar.set_postfix(phase=rec["phase"], loss=f"{rec['loss_brdf']:.4f}", kl=f"{rec['loss_kl']:.3f}")
                    if listener is not None:
                        listener(self.step, cfg.iterations, rec)
                bar.update(1)
                if self.step % cfg.checkpoint_every == 0:
                    self.save()
            self.finish()
            self.fit_environment()
        except KeyboardInterrupt:
            self.save()
            bar.close()
            raise TrainingInterrupted(f"interrupted at step {self.step}; checkpoint saved to "
                                      f"{self.checkpoint_path} (rerun with --resume)") from None
        bar.close()
        self.save()
        return self.model
