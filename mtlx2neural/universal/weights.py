"""The shipped universal networks: one file per shading model in ``mtlx2neural/universal/weights/``.

A file (``<model>.pt``, torch's format, a few hundred kilobytes) holds a dict:

- ``model``: the shading model (:data:`~mtlx2neural.universal.canonical.SHADING_MODELS` key);
- ``channels``: ``[[canonical name, width], ...]``, the parameter stack's layout the encoder reads
  (:func:`~mtlx2neural.universal.canonical.canonical_names`);
- ``shape``: the :data:`~mtlx2neural.train.shared.SHAPE_FIELDS` of the network's own settings that a
  material's settings must share to use it (latent channels, frames, decoder, heads);
- ``encoder``, ``decoder``, ``sampler``: the networks' state dicts (the decoder's holds the
  environment head);
- ``input`` (absent: the raw channels): what the encoder reads, the atlas's
  :meth:`~mtlx2neural.train.encoder_input.EncoderInput.statistics`: every channel standardised by the
  atlas's fixed mean and deviation (a material's own statistics would move every code the encoder gives),
  then log(alpha) of the named lobes;
- ``provenance``: how it was trained (command, steps, atlas size and seed, seconds, torch version,
  final losses), so ``python -m mtlx2neural.universal.train`` can reproduce it.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
from pathlib import Path

import torch

from mtlx2neural.atomic import atomic_path

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
NETWORK_FIELDS = ("latent_dim", "frames", "decoder", "albedo_head", "analytic_cosine")
"""Settings that decide the shipped networks' shape (the environment head is also needed: a material's
settings must fit one, ``environment_fraction`` > 0)."""


def weights_path(model: str, folder: Path | None = None) -> Path:
    return Path(folder or WEIGHTS_DIR) / f"{model}.pt"


def save_weights(path: Path, data: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        torch.save(data, tmp)


def weights_digest(weights: dict) -> str:
    """SHA-256 of a network's layout and every tensor of its encoder, decoder and sampler."""
    h = hashlib.sha256(repr(weights["channels"]).encode())
    if weights.get("input"):
        h.update(repr(weights["input"]).encode())
    for part in ("encoder", "decoder", "sampler"):
        for k, v in sorted(weights[part].items()):
            h.update(k.encode())
            h.update(v.detach().cpu().numpy().tobytes())
    return h.hexdigest()


@functools.lru_cache(maxsize=8)
def _load(path: str, mtime: float) -> dict:
    data = torch.load(path, map_location="cpu", weights_only=False)
    return {**data, "sha256": weights_digest(data)}  # hashed once per file and process


def load_weights(model: str, folder: Path | None = None) -> dict | None:
    """The shipped network of ``model`` (module docstring, plus its ``sha256``: :func:`weights_digest`), or
    None when there is none."""
    path = weights_path(model, folder)
    if not path.is_file():
        return None
    return _load(str(path), path.stat().st_mtime)


def input_mode(weights: dict) -> str:
    """What the shipped encoder reads (an ``encoder_input`` mode): ``raw`` for a file without ``input``."""
    return (weights.get("input") or {}).get("mode", "raw")


def shape_mismatch(weights: dict, cfg) -> list[str]:
    """The settings of ``cfg`` (a TrainConfig) that the shipped network cannot serve: its
    :data:`NETWORK_FIELDS` that differ, and ``environment_fraction`` when the settings fit no head. Not
    ``encoder_input``: the shipped encoder reads what it was trained on, and a material on the universal
    path is planned with that (:func:`universal_config`)."""
    out = [f for f in NETWORK_FIELDS if getattr(cfg, f) != weights["shape"][f]]
    if cfg.environment_steps <= 0:
        out.append("environment_fraction")
    return out


def universal_config(cfg, weights: dict):
    """``cfg`` (a TrainConfig) as a material on the universal path trains with it: the shipped encoder's input
    mode (:func:`input_mode`; its statistics are the atlas's), whatever ``cfg`` asked of its own encoder."""
    return dataclasses.replace(cfg, encoder_input=input_mode(weights))
