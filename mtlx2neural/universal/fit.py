"""Convert a material with its shading model's universal network: encode, then fine-tune briefly.

:func:`fit_universal` takes a :class:`~mtlx2neural.train.trainer.Trainer` built for the material's
canonical form (:mod:`.canonical`: its stack then has the layout the shipped encoder reads) and:

1. loads the shipped encoder, decoder (with its environment head) and sampler (:mod:`.weights`);
2. bakes: the encoder runs over every texel of every level of the material's parameter pyramid;
3. fine-tunes for ``steps`` steps on the material's own training rows (each step on
   :data:`~mtlx2neural.universal.choice.FINE_TUNE_ROWS` rows), Adam with a cosine decay from
   :data:`LR_START` to the settings' ``lr_end`` (a block-compressed ``latent_format`` reads the latents
   through its codec in the last ``block_fraction``), with ``tune`` (:data:`TUNES`):

   - ``networks``: the latents, the decoder and the sampler. The material gets its own copy of the
     networks, fitted to it: measured on the scene sample (``fast``, 900 steps of 1024 rows, the 2026-12-06
     networks), HDR FLIP 0.030 on the leaf where its own 1000-step training reaches 0.038, 0.012 on the lava
     against 0.011, in under half the conversion's time (BENCHMARKS.md, "Whole scenes");
   - ``latents``: the latents alone, the networks frozen, so the shipped decoder and sampler stay byte
     for byte and every material converted so shares them; the leaf then scored 0.156, the lava 0.100
     (the raw-input networks of 2026-12-05: the universal decoder alone does not resolve them);
4. finishes as a training run does (a cut-out's empty texels, the codec). With ``networks`` the
   environment head is fitted again (``environment_fraction`` of the fine-tune's steps: the sampler's
   lobes moved); with ``latents`` the shipped head serves.
"""

from __future__ import annotations

import dataclasses
import math

import torch

from mtlx2neural.model.networks import Encoder
from mtlx2neural.train.adam import Adam
from mtlx2neural.train.encoder_input import EncoderInput
from mtlx2neural.train.replay import RowReplay
from mtlx2neural.universal.canonical import SHADING_MODELS, canonical_name
from mtlx2neural.universal.choice import FINE_TUNE_ROWS, STEPS, TUNES
from mtlx2neural.universal.weights import universal_config

LR_START = 5e-3
"""The latents' learning rate at the fine-tune's first step (the codes start close: a large first step
moves them to the material's own targets within the few steps the fine-tune has)."""
PREFETCH = 16
"""Steps whose training rows the fine-tune draws in one call to the reference (``TrainConfig.target_prefetch``):
its mollification angle stays at the floor, so drawing ahead changes only the cost (lava, 300 steps on 2 cores:
training 17.4 -> 11.6 s, HDR FLIP 0.0220 -> 0.0224)."""


class LayoutMismatch(ValueError):
    """The material's stack does not have the layout the shipped encoder reads."""


def encoder_columns(stack, weights: dict) -> torch.Tensor:
    """The stack's raw columns, in the order the shipped encoder reads them: its channels matched by
    canonical name and width. A channel of the stack that the network lacks is skipped when it holds the
    model's neutral value (:attr:`~.canonical.ShadingModel.neutral`) over the finest level. Raises
    :class:`LayoutMismatch` otherwise, naming the channels."""
    neutral = SHADING_MODELS[weights["model"]].neutral
    offsets, o = {}, 0
    for c in stack.channels:
        offsets[canonical_name(c.name)] = (o, c.width)
        o += c.width
    want = {n: w for n, w in weights["channels"]}
    missing = [n for n, w in want.items() if offsets.get(n, (0, w))[1] != w or n not in offsets]
    extra = []
    for n, (start, width) in offsets.items():
        if n in want:
            continue
        level0 = stack.levels[0][start:start + width].float().reshape(width, -1)
        value = torch.tensor(neutral.get(n, [math.nan] * width), dtype=torch.float32)[:, None]
        if not torch.allclose(level0, value.expand_as(level0), atol=1e-5):
            extra.append(n)
    if missing or extra:
        raise LayoutMismatch(f"the parameter stack's channels differ from the universal {weights['model']} "
                             f"network's (missing {missing or 'none'}, not neutral {extra or 'none'})")
    return torch.cat([torch.arange(offsets[n][0], offsets[n][0] + w) for n, w in weights["channels"]])


def encoder_input(stack, weights: dict) -> EncoderInput:
    """The shipped encoder's input on ``stack``: its columns in the shipped layout (:func:`encoder_columns`), as
    they are (a file without ``input``) or standardised by the atlas's statistics, with log roughness of its
    lobes (:meth:`~mtlx2neural.train.encoder_input.EncoderInput.fixed`). Raises :class:`LayoutMismatch` when the
    channels differ (:func:`encoder_columns`) or a lobe whose roughness the encoder reads (named canonically)
    is not a LEAN lobe of ``stack``."""
    spec = weights.get("input")
    if spec:
        lobes = {canonical_name(lobe): lobe for lobe in getattr(stack, "lean_groups", None) or []}
        lost = [lobe for lobe in spec["lobes"] if lobe not in lobes]
        if lost:
            raise LayoutMismatch(f"the universal {weights['model']} network reads the roughness of lobes the "
                                 f"material lacks ({', '.join(lost)})")
        spec = {**spec, "lobes": [lobes[lobe] for lobe in spec["lobes"]]}
    return EncoderInput.fixed(stack, encoder_columns(stack, weights), spec)


def load_encoder(trainer, weights: dict) -> None:
    """Give ``trainer``'s model the shipped encoder, reading the stack as the network was trained to
    (:func:`encoder_input`; raises :class:`LayoutMismatch`). Call before the optimiser is made: the
    encoder is a new module. ``trainer.cfg.encoder_input`` becomes the shipped one's mode (the material's
    own encoder's setting does not apply)."""
    columns = encoder_input(trainer.stack, weights)
    trainer.cfg = universal_config(trainer.cfg, weights)
    trainer.encoder_input = columns
    trainer.model.encoder = Encoder(columns.dim, trainer.cfg.latent_dim).to(trainer.device)
    trainer.model.encoder.load_state_dict(weights["encoder"])


def load_networks(model, weights: dict) -> None:
    """The shipped decoder (its environment head included; one shipped before the sharp lobe reads as one whose
    sharp lobe carries nothing: :func:`~mtlx2neural.formats.weights.upgrade_environment_head`) and sampler,
    into ``model``'s."""
    model.decoder.load_state_dict(weights["decoder"])
    model.sampler.load_state_dict(weights["sampler"])


def use_fine_tune_schedule(trainer, steps: int, rows: int = FINE_TUNE_ROWS) -> None:
    """Replace ``trainer``'s schedule with the fine-tune's: ``steps`` iterations of ``rows`` rows
    (:data:`~mtlx2neural.universal.choice.FINE_TUNE_ROWS`; not the preset's batch), no encoder phase, Adam from
    :data:`LR_START`, the mollification at its floor throughout (as the shipped decoder ended its training), rows
    drawn :data:`PREFETCH` steps at a time, no FLIP probe, and no updates of the energy balance
    (:mod:`mtlx2neural.train.energy_balance`): the shipped networks start the fine-tune with their energy
    settled, and the balance's updates then only cost. Scene sample, ``--network scene --encoder universal``
    (300 joint steps, 2026-12-07): with the balance 41.3 s, HDR FLIP 0.087, the near-mirror Gold keeping 0.89 of
    its energy; without, 28.9 s, 0.0855, 0.98. The run still ends with the balance's calibration when
    ``trainer`` was built to balance (``Trainer.calibrates``): its levels' energy is then in the band."""
    cfg = trainer.cfg
    trainer.cfg = dataclasses.replace(cfg, iterations=max(1, steps), encoder_fraction=0.0, lr_start=LR_START,
                                      batch=max(1, int(rows)), probe_every=0, energy_gain=0.0,
                                      mollify_degrees=cfg.mollify_min_degrees,
                                      target_prefetch=max(cfg.target_prefetch, PREFETCH))
    trainer.replay = RowReplay(trainer.cfg.batch, cfg.target_reuse, trainer.cfg.target_prefetch)


def fit_universal(trainer, weights: dict, steps: int = STEPS, progress: bool = True, tune: str = "networks"):
    """Steps 1-4 of the module docstring on ``trainer`` (its ``cfg`` is replaced by the fine-tune's: ``steps``
    iterations, no encoder phase, the mollification at its floor throughout, as the shipped decoder
    ended its training, rows drawn :data:`PREFETCH` steps at a time). Saves the checkpoint and returns the model."""
    if tune not in TUNES:
        raise ValueError(f"tune {tune!r}: choose one of {TUNES}")
    load_encoder(trainer, weights)
    model = trainer.model
    load_networks(model, weights)
    use_fine_tune_schedule(trainer, steps)
    trainer.bake()
    for p in (*model.decoder.parameters(), *model.sampler.parameters()):
        p.requires_grad_(tune == "networks")
    tuned = [p for p in model.parameters() if p.requires_grad]
    trainer.opt = Adam(tuned, lr=LR_START, betas=(0.9, 0.999), eps=1e-7)
    # The shipped environment head serves frozen networks; a tuned sampler has other lobes: fit it again.
    trainer.environment_history = [] if tune == "networks" else [
        {"step": 0, "universal": weights["model"], "frozen": True}]
    try:
        return trainer.run(progress=progress)
    finally:
        for p in (*model.decoder.parameters(), *model.sampler.parameters()):
            p.requires_grad_(True)
