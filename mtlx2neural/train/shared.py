"""Training several materials with one network: a shared BRDF decoder (environment head included) and
one sampler, each material keeping its own latent pyramid and encoder (``--network scene``).

:class:`SharedTrainer` drives one :class:`~mtlx2neural.train.trainer.Trainer` per material, built as
for a per-material run, after tying their models' ``decoder`` and ``sampler`` to the first's:

1. **Joint steps** (``cfg.iterations``, the per-material schedule: encoder phase, bake, fine-tune):
   every step takes :data:`MATERIALS_PER_STEP` of the M materials (all of them when there are fewer),
   in turn from a seeded shuffle so that each gets the same share of the steps, draws each one's own
   batch (its trainer's ``cfg.batch`` rows: the caller sizes it, :func:`scene_batch`), sums their
   losses weighted 1/K, and takes one Adam step over every parameter (the shared networks', each
   encoder's or latent pyramid's). The K batches go through the shared networks in one pass
   (:func:`~.losses.segment_losses`: each batch's losses as its own), which costs less than K passes.
   A joint step so costs about what one material's step costs, whatever the number of materials. Each
   material keeps its own energy balance (:mod:`.energy_balance`: its levels' loss quantiles). Once
   a material's mollification angle is at its floor, its rows are drawn :data:`FLOOR_PREFETCH` of its
   steps at a time (:meth:`SharedTrainer._prefetch_at_floor`).
2. **Latent fine-tune**: the shared networks frozen, each material's latents alone for
   ``latent_steps`` steps (Adam at ``lr_end``), so a material whose codes the joint phase left rough
   fits the network that ships. Every material's batch of a step goes through the networks in one pass.
3. **Environment head**: fitted once on rows of every material (:func:`.environment_fit.fit_environment_head`).

The rows of phases 1 and 2 never depend on the networks: :meth:`SharedTrainer.requests` lists every draw the
run will make, so that a :class:`~.row_process.RowProcess` can draw them in another process
(:meth:`SharedTrainer.use_rows`) while this one trains.

Each trainer then saves its checkpoint as a per-material run does; every checkpoint holds the same
decoder and sampler weights. The materials must share the network's shape (latent channels, frames,
decoder size, heads): :class:`SharedTrainer` raises ``ValueError`` otherwise.

A material added to a group that is already trained (:func:`fit_into_network`) trains its encoder and
latents alone against the group's networks, frozen: the per-material schedule (encoder phase, bake,
latent fine-tune) shortened to :data:`ADDED_FRACTION` of ``cfg.iterations``, no environment fit. Its
checkpoint then holds the group's weights byte for byte, so the network that ships is unchanged.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time

import torch

from mtlx2neural.progress import progress_bar
from mtlx2neural.train.adam import Adam
from mtlx2neural.train.environment_fit import fit_environment_head
from mtlx2neural.train.grad_clip import SpikeClip
from mtlx2neural.train.losses import brdf_loss_of, raw_floor, segment_losses
from mtlx2neural.train.replay import RowReplay
from mtlx2neural.train.row_process import RemoteReplay, Request, RowProcess
from mtlx2neural.train.trainer import Trainer, _lr, at_mollify_floor

SCENE_MIN_ROWS = 256
"""The fewest rows per material in a joint step (a smaller share leaves a material's batch too noisy)."""
MATERIALS_PER_STEP = 4
"""Materials in one joint step (K): the joint phase's cost then does not grow with the scene's size."""
LATENT_FRACTION = 0.2
"""Latent fine-tune steps per material, as a share of ``cfg.iterations`` (:func:`latent_steps`)."""
FLOOR_PREFETCH = 16
"""Steps whose rows a material draws in one call to the reference (``TrainConfig.target_prefetch``) once its
mollification angle is at its floor: in the joint steps after the angle's decay, and in the latent fine-tune.
The reference's per-call cost dominates a material's 512-row share of a step on a CPU (chess set, 15
materials at 64²: a joint step took 206 ms, of which drawing rows about three quarters)."""
SHAPE_FIELDS = ("latent_dim", "frames", "decoder", "albedo_head", "analytic_cosine", "environment_fraction",
                "iterations", "encoder_fraction", "lr_start", "lr_end")


ADDED_FRACTION = 0.5
"""Steps of an added material's fit (:func:`fit_into_network`), as a share of ``cfg.iterations``."""


def shape_differences(cfg, other) -> list[str]:
    """The :data:`SHAPE_FIELDS` in which two configs (``TrainConfig`` or its dict) differ."""
    get = (lambda c, f: c[f]) if isinstance(other, dict) else getattr
    return [f for f in SHAPE_FIELDS if getattr(cfg, f) != get(other, f)]


def scene_batch(batch: int, materials: int) -> int:
    """Rows per material in a joint step: the preset's batch split between the materials of a step
    (:data:`MATERIALS_PER_STEP` at most), at least :data:`SCENE_MIN_ROWS`."""
    return max(SCENE_MIN_ROWS, batch // max(1, min(materials, MATERIALS_PER_STEP)))


def floor_prefetch(cfg) -> int:
    """The prefetch of a material's rows once its mollification angle is at its floor (:data:`FLOOR_PREFETCH`,
    or its own ``target_prefetch`` when larger)."""
    return max(cfg.target_prefetch, FLOOR_PREFETCH)


def latent_steps(iterations: int) -> int:
    """Steps of each material's latent fine-tune for a ``iterations``-step schedule."""
    return round(LATENT_FRACTION * iterations)


def _unique_parameters(modules) -> list[torch.nn.Parameter]:
    seen, out = set(), []
    for m in modules:
        for p in m.parameters():
            if id(p) not in seen:
                seen.add(id(p))
                out.append(p)
    return out


class SharedTrainer:
    """Joint training of several materials' trainers with one decoder and one sampler (module docstring)."""

    def __init__(self, trainers: list[Trainer]):
        if not trainers:
            raise ValueError("a shared network needs at least one material")
        lead = trainers[0]
        for t in trainers[1:]:
            differ = shape_differences(t.cfg, lead.cfg)
            if differ:
                raise ValueError(f"{t.out_dir.name}: its settings differ from {lead.out_dir.name}'s in {differ}; "
                                 f"materials sharing a network train with one schedule and one network shape")
            t.model.decoder = lead.model.decoder
            t.model.sampler = lead.model.sampler
        self.trainers = trainers
        self.cfg = lead.cfg
        self.params = _unique_parameters(t.model for t in trainers)
        self.opt = Adam(self.params, lr=self.cfg.lr_start, betas=(0.9, 0.999), eps=1e-7)
        self.clip = SpikeClip()  # the joint steps' gradient-norm spike guard (train.grad_clip)
        for t in trainers:
            t.opt = self.opt  # a trainer's checkpoint stores the shared optimiser's state
        self.step = 0
        self.history: list[dict] = []
        self.seconds: dict[str, float] = {}
        self.gen = torch.Generator().manual_seed(self.cfg.seed)  # the order materials take their steps in
        losses = functools.partial(segment_losses, brdf_terms=brdf_loss_of(self.cfg.brdf_loss, self.cfg.brdf_eps,
                                                                           terms=True),
                                   floor=raw_floor(self.cfg.brdf_floor))
        self._segment_losses = torch.compile(losses) if self.cfg.compile else losses
        self._queue: list[int] = []
        self.remote = False  # rows from a RowProcess (use_rows)

    def _next_indices(self) -> list[int]:
        """The K materials of the next joint step (indices): the next ones of a seeded shuffle of all M,
        reshuffled when it runs out (a material never twice in one step)."""
        k = min(MATERIALS_PER_STEP, len(self.trainers))
        if len(self._queue) < k:
            rest = set(self._queue)
            fresh = [i for i in torch.randperm(len(self.trainers), generator=self.gen).tolist() if i not in rest]
            self._queue += fresh
        picked, self._queue = self._queue[:k], self._queue[k:]
        return picked

    def _next_materials(self) -> list[Trainer]:
        return [self.trainers[i] for i in self._next_indices()]

    def requests(self) -> list[Request]:
        """Every batch :meth:`run` will train on from here, in order (:class:`.row_process.Request`):
        each joint step's materials, with the prefetch :meth:`_prefetch_at_floor` gives them at that step,
        then the latent fine-tune's steps, every material in each (:meth:`fit_latents`: a fresh replay at the
        floor's prefetch)."""
        state, queued = self.gen.get_state(), list(self._queue)
        try:
            picks = [self._next_indices() for _ in range(self.step, self.cfg.iterations)]
        finally:
            self.gen.set_state(state)
            self._queue = queued
        start = {k: t.replay.prefetch for k, t in enumerate(self.trainers)}
        out, seen = [], set()
        for s, step_picks in zip(range(self.step, self.cfg.iterations), picks):
            for k in step_picks:
                t = self.trainers[k]
                floor = floor_prefetch(t.cfg)
                prefetch = floor if start[k] < floor and at_mollify_floor(t.cfg, s) else start[k]
                out.append(Request(k, s, prefetch, fresh=k not in seen))
                seen.add(k)
        for i in range(latent_steps(self.cfg.iterations)):  # every material in each step of the fine-tune
            out += [Request(k, self.cfg.iterations, floor_prefetch(t.cfg), fresh=i == 0)
                    for k, t in enumerate(self.trainers)]
        return out

    def use_rows(self, rows: RowProcess) -> None:
        """Take every material's rows from ``rows`` (planned with :meth:`requests`) from now on."""
        for k, t in enumerate(self.trainers):
            t.replay = RemoteReplay(rows, k, t.device)
        self.remote = True

    @property
    def model_count(self) -> int:
        return len(self.trainers)

    def joint_step(self) -> dict:
        """One Adam step on the sum of the step's materials' losses (weight 1/K). Returns the step's record
        (their mean losses) and appends each of them its own record to its trainer's history."""
        picked = self._next_materials()
        m = len(picked)
        self.opt.zero_grad(set_to_none=True)
        parts = self._losses_of(picked)
        (sum(loss for loss, _, _ in parts) / m).backward()
        parts = [(brdf.detach(), kl.detach()) for _, brdf, kl in parts]
        for group in self.opt.param_groups:
            group["lr"] = _lr(self.cfg, self.step)
        grad_norm, clipped = self.clip(self.params)
        self.opt.step()
        self.step += 1
        for t in self.trainers:
            t.step = self.step
        for t, (lb, lk) in zip(picked, parts):
            t.clipped_steps += clipped
            t.history.append({**t.step_record(lb, lk, grad_norm), "seconds": round(time.time() - self._t0, 2)})
        return {"step": self.step, "loss_brdf": float(sum(lb for lb, _ in parts)) / m,
                "loss_kl": float(sum(lk for _, lk in parts)) / m, "grad_norm": grad_norm}

    def _losses_of(self, trainers: list[Trainer]) -> list[tuple]:
        """Each trainer's ``(total, brdf, kl)`` loss on its next batch (:meth:`Trainer.step_rows`), as its
        ``step_loss`` gives it; batches of one size go through the shared networks in one pass
        (:func:`~.losses.segment_losses`)."""
        batches = [t.step_rows() for t in trainers]
        if len({b.wi.shape[0] for b in batches}) == 1:
            cat = [torch.cat(parts) for parts in zip(*((b.latent, b.wi, b.wo, b.target, b.u_kl) for b in batches))]
            lead = trainers[0].model
            tau = None  # each material's rows at their own levels' quantiles (0.5 without a balance)
            if any(b.tau is not None for b in batches):
                tau = torch.cat([b.tau if b.tau is not None else torch.full_like(b.wi[:, 0], 0.5) for b in batches])
            brdf, kl = self._segment_losses(lead.decoder, lead.sampler, *cat, segments=len(batches), tau=tau,
                                            lift=any(b.lift for b in batches))
            out = list(zip(brdf + kl, brdf, kl))
        else:  # batches of different sizes: one at a time
            out = []
            for t, b in zip(trainers, batches):
                loss_brdf, loss_kl = t._losses(t.model.decoder, t.model.sampler, b.latent, b.wi, b.wo, b.target,
                                               b.u_kl, tau=b.tau, lift=b.lift)
                out.append((loss_brdf + loss_kl, loss_brdf, loss_kl))
        return [(loss + t.albedo_term(b), brdf, kl) if t.cfg.albedo_head else (loss, brdf, kl)
                for t, b, (loss, brdf, kl) in zip(trainers, batches, out)]

    def _prefetch_at_floor(self) -> None:
        """From the step at which a material's mollification angle reaches its floor (where it then stays),
        draw its rows :data:`FLOOR_PREFETCH` of its steps at a time: the same settings for every row drawn
        ahead, so the same distribution of rows, at a lower cost per row."""
        if self.remote:  # planned in the requests
            return
        for t in self.trainers:
            prefetch = floor_prefetch(t.cfg)
            if t.replay.prefetch < prefetch and at_mollify_floor(t.cfg, t.step):
                t.replay.set_prefetch(prefetch)

    def fit_latents(self, steps: int) -> None:
        """The latent fine-tune: every material's latents, the shared networks frozen, ``steps`` steps. Each
        material's loss gives gradients to its own latents only, and Adam updates each parameter on its own,
        so training them together is the fine-tune of each alone; one pass of the networks per step
        (:meth:`_losses_of`) costs less than one per material."""
        if steps <= 0:
            return
        if not self.remote:  # a row process has these fresh replays in its requests
            for t in self.trainers:  # the mollification stays at its floor from here on: rows drawn ahead
                cfg = t.cfg
                t.replay = RowReplay(cfg.batch, cfg.target_reuse, floor_prefetch(cfg))
        lead = self.trainers[0].model  # every trainer's decoder and sampler are the lead's
        shared = _unique_parameters([lead.decoder, lead.sampler])
        for p in shared:
            p.requires_grad_(False)
        try:
            opt = Adam(_unique_parameters(t.model.latents for t in self.trainers), lr=self.cfg.lr_end,
                       betas=(0.9, 0.999), eps=1e-7)
            for _ in range(steps):
                parts = self._losses_of(self.trainers)
                opt.zero_grad(set_to_none=True)
                sum(loss for loss, _, _ in parts).backward()
                opt.step()
                for t, (loss, _, _) in zip(self.trainers, parts):
                    if not math.isfinite(loss.item()):
                        raise FloatingPointError(f"{t.out_dir.name}: non-finite loss in the latent fine-tune")
        finally:
            for p in shared:
                p.requires_grad_(True)

    def run(self, progress: bool = True, listener=None) -> list:
        """All three phases (module docstring); saves every trainer's checkpoint and returns the models.
        ``listener(step, total, record)``: called every 25 joint steps. ``seconds`` holds each phase's
        wall time (``joint``, ``latents``, ``environment``)."""
        cfg = self.cfg
        switch = int(cfg.iterations * cfg.encoder_fraction)
        self._t0 = t0 = time.time()
        bar = progress_bar(cfg.iterations, self.step, enabled=progress, desc=f"{len(self.trainers)} materials")
        while self.step < cfg.iterations:
            if self.step >= switch:  # some may be baked already (a universal start, pipeline.scene_network)
                for t in self.trainers:
                    if not t.baked:
                        t.bake()
            self._prefetch_at_floor()
            rec = self.joint_step()
            if not all(math.isfinite(rec[k]) for k in ("loss_brdf", "loss_kl", "grad_norm")):
                raise FloatingPointError(f"non-finite loss at joint step {self.step}: {rec}")
            for t in self.trainers:  # each material's energy balance (train.energy_balance), when one is due
                balanced = t.balance_energy()
                if balanced and t.history and t.history[-1]["step"] == self.step:
                    t.history[-1].update(balanced)
                elif balanced:
                    t.history.append({"step": self.step, **balanced})
            if self.step % 25 == 0 or self.step == cfg.iterations:
                rec["seconds"] = round(time.time() - t0, 2)
                self.history.append(rec)
                bar.set_postfix(loss=f"{rec['loss_brdf']:.4f}")
                if listener is not None:
                    listener(self.step, cfg.iterations, rec)
            bar.update(1)
        bar.close()
        self.seconds["joint"] = round(time.time() - t0, 2)
        t1 = time.time()
        for t in self.trainers:
            t.finish(calibrate=False)
        self.fit_latents(latent_steps(cfg.iterations))
        for t in self.trainers:  # each material's codes, after the latent fine-tune has moved them
            t.calibrate_energy()
        self.seconds["latents"] = round(time.time() - t1, 2)
        t2 = time.time()
        if cfg.environment_steps > 0:
            history = fit_environment_head_shared(self.trainers, cfg.environment_steps, cfg.environment_batch)
            for t in self.trainers:
                t.environment_history = [dict(r) for r in history]
        self.seconds["environment"] = round(time.time() - t2, 2)
        for t in self.trainers:
            t.model.zero_grad(set_to_none=True)
            t.save()
        return [t.model for t in self.trainers]


def fit_environment_head_shared(trainers: list[Trainer], steps: int, batch: int) -> list[dict]:
    """The shared environment head fitted on rows of every material (:mod:`.environment_fit`)."""
    t = time.time()
    history = fit_environment_head(trainers, steps, batch)
    if history:
        history[-1]["seconds"] = round(time.time() - t, 2)
    return history


def fit_into_network(trainer: Trainer, network, environment_history: list[dict], progress: bool = True):
    """Train a material added to an already-trained group (module docstring): ``trainer``'s model takes
    ``network``'s (a :class:`~mtlx2neural.model.neural_material.NeuralMaterial` of the group) decoder,
    environment head and sampler, frozen, and its encoder and latents train for ``ADDED_FRACTION`` of its
    schedule. ``environment_history``: the group's environment fit, recorded in the checkpoint (the head
    is not fitted again). Saves the checkpoint and returns the model."""
    cfg = trainer.cfg
    trainer.cfg = dataclasses.replace(cfg, iterations=max(1, round(ADDED_FRACTION * cfg.iterations)))
    trainer.model.decoder, trainer.model.sampler = network.decoder, network.sampler
    for p in _unique_parameters([network.decoder, network.sampler]):
        p.requires_grad_(False)
    own = [p for p in trainer.model.parameters() if p.requires_grad]  # the encoder, the latents
    trainer.opt = Adam(own, lr=cfg.lr_start, betas=(0.9, 0.999), eps=1e-7)
    trainer.environment_history = [dict(r) for r in environment_history] or [{"step": 0, "frozen": True}]
    return trainer.run(progress=progress)
