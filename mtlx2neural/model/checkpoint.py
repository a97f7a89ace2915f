"""Load a trained :class:`NeuralMaterial` from the trainer's ``checkpoint.pt``.

The trainer saves ``{"model": state_dict, "config": asdict(TrainConfig), "step",
"baked", ...}``. The constructor's arguments are recovered from the state dict's
shapes where they are not in the config:

- ``resolution`` (h, w): the latent pyramid's level 0 (``latents.levels.0``, [C, h, w], or
  [T, C, h, w] for a UDIM material, whose trained tiles are the buffer ``latents.tiles``, UDIM
  numbers in the order of the leading axis; the trainer also saves them as ``"udim_tiles"``);
- ``latent_dim``: its channel count C;
- ``in_dim``: the encoder's first Linear ``in_features``; the encoder of a uniform
  material has ``in_dim = 0`` but a 1-wide layer, so a 1-wide encoder over a 1x1
  pyramid reads as uniform (the encoder is not used once the latents are baked);
- ``frames``: the decoder's frame layer rows / 6; ``decoder``: its hidden widths;
- ``albedo_head``: whether ``decoder.albedo.*`` weights are present;
- ``environment_head``: whether ``decoder.environment.*`` weights are present;
- ``latent_format``: the block format of ``latents.codec.codec_format`` (``exr`` without one);
- ``analytic_cosine``: the config's, and False for a config without the key (checkpoints
  made before the option, whose networks learned f * cos themselves).

Config keys that NeuralMaterial's constructor also takes (and the shapes do not
fix) are passed on; all other config keys (e.g. training-only settings) are ignored. The model is returned in eval mode on ``map_location``.
"""

from __future__ import annotations

import inspect
import warnings
from pathlib import Path

import torch

from mtlx2neural.errors import InputError
from mtlx2neural.formats.latent_codec import format_of_code
from mtlx2neural.model.neural_material import NeuralMaterial


def checkpoint_file(path) -> Path:
    """``path`` itself, or ``path/checkpoint.pt`` when ``path`` is a folder (or, missing, not a ``.pt``)."""
    p = Path(path)
    return p / "checkpoint.pt" if p.is_dir() or (not p.exists() and p.suffix != ".pt") else p


def _linear_widths(state: dict, prefix: str) -> list[int]:
    """Output widths of the Linear layers ``prefix.<i>.weight`` in layer order."""
    keys = sorted((int(k[len(prefix):].split(".")[0]), k) for k in state
                  if k.startswith(prefix) and k.endswith(".weight"))
    return [state[k].shape[0] for _, k in keys]


def model_arguments(state: dict, config: dict | None = None) -> dict:
    """NeuralMaterial constructor arguments recovered from a state dict (see the module docstring)."""
    config = config or {}
    level0 = state["latents.levels.0"]
    latent_dim, h, w = (int(s) for s in level0.shape[-3:])
    tiles = state.get("latents.tiles")
    enc_in = int(state["encoder.net.0.weight"].shape[1])
    in_dim = 0 if (enc_in == 1 and (h, w) == (1, 1)) else enc_in
    frame_w = state.get("decoder.frame_layer.weight")
    frames = int(frame_w.shape[0]) // 6 if frame_w is not None else 0  # no frame layer: the frames=0 ablation
    hidden = tuple(_linear_widths(state, "decoder.net.")[:-1]) or config.get("decoder", "2x32")
    args = {"resolution": (h, w), "in_dim": in_dim, "latent_dim": latent_dim, "frames": frames,
            "decoder": hidden, "albedo_head": any(k.startswith("decoder.albedo.") for k in state),
            "environment_head": any(k.startswith("decoder.environment.") for k in state),
            "analytic_cosine": bool(config.get("analytic_cosine", False)),
            "tiles": None if tiles is None else [int(t) for t in tiles],
            "latent_format": format_of_code(state.get("latents.codec.codec_format"))}
    # Forward compatibility: constructor options that only the config records (e.g. a decoder ablation).
    accepted = inspect.signature(NeuralMaterial).parameters
    args.update({k: v for k, v in config.items() if k in accepted and k not in args})
    return args


def read_checkpoint(f, map_location="cpu", remedy: str = "retrain it") -> dict:
    """The trainer's checkpoint dict in the file ``f``; :class:`InputError` naming the file when it
    cannot be read (truncated, foreign, permission denied), with ``remedy`` as the advice."""
    f = Path(f)
    try:
        ck = torch.load(f, map_location=map_location, weights_only=False)
    except PermissionError:
        raise InputError(f"{f}: cannot read the checkpoint: permission denied; fix its permissions, or "
                         f"{remedy}") from None
    except Exception as exc:  # noqa: BLE001 - torch raises many types for truncated or foreign files
        raise InputError(f"{f}: cannot read the checkpoint, it is truncated or not a checkpoint "
                         f"({type(exc).__name__}: {exc}); {remedy}") from None
    if not isinstance(ck, dict) or not isinstance(ck.get("model"), dict):
        raise InputError(f"{f}: not a mtlx2neural checkpoint (expected a dict with a 'model' state dict); {remedy}")
    return ck


RESUME_FIELDS = ("decoder", "frames", "latent_dim", "albedo_head", "analytic_cosine")
"""Settings a resumed run must share with its checkpoint: they fix the network's shape."""


def resume_conflicts(ck: dict, settings: dict, grid: tuple[int, int], tiles=None) -> list[str]:
    """What differs between the checkpoint ``ck`` and a run with ``settings`` (a TrainConfig as a
    dict), latent ``grid`` (H, W) and, when given, UDIM ``tiles``: one ``"name: checkpoint X, this run
    Y"`` per difference."""
    config, state = ck.get("config") or {}, ck["model"]
    out = [f"{k}: checkpoint {config[k]!r}, this run {settings.get(k)!r}"
           for k in RESUME_FIELDS if k in config and config[k] != settings.get(k)]
    level0 = state.get("latents.levels.0")
    if level0 is not None and tuple(level0.shape[-2:]) != tuple(grid):
        out.append(f"latent grid: checkpoint {level0.shape[-1]}x{level0.shape[-2]}, this run {grid[1]}x{grid[0]}")
    if tiles is not None:
        have = state.get("latents.tiles")
        have = None if have is None else [int(t) for t in have]
        if have != (None if tiles is None else sorted(tiles)):
            out.append(f"UDIM tiles: checkpoint {have}, this run {sorted(tiles)}")
    return out


def load_checkpoint(path, map_location="cpu") -> NeuralMaterial:
    """The NeuralMaterial saved at ``path`` (a ``checkpoint.pt`` or the folder holding one), in eval
    mode (``train(False)``: ``NeuralMaterial.eval`` is the BRDF).

    Raises InputError naming the file when it is missing, unreadable or not a
    trainer checkpoint. Warns when the checkpoint predates the latent bake (its
    latent pyramid is then untrained).
    """
    f = checkpoint_file(path)
    if not f.is_file():
        raise InputError(f"{f}: no neural-material checkpoint there; train one with "
                         f"`mtlx2neural ASSET` or pass --checkpoint PATH")
    ck = read_checkpoint(f, map_location, "retrain or point --checkpoint at a complete checkpoint.pt")
    return model_from_checkpoint(ck, f, map_location)


def model_from_checkpoint(ck: dict, f, map_location="cpu") -> NeuralMaterial:
    """The NeuralMaterial of a checkpoint dict ``ck`` already read from the file ``f`` (:func:`read_checkpoint`),
    as :func:`load_checkpoint` returns it; the same errors and warning, naming ``f``."""
    state, config = ck["model"], ck.get("config") or {}
    try:
        model = NeuralMaterial(**model_arguments(state, config))
        model.load_state_dict(state)
    except (KeyError, RuntimeError, ValueError, IndexError) as exc:
        raise InputError(f"{f}: the checkpoint does not match the NeuralMaterial layout "
                         f"({type(exc).__name__}: {exc})") from None
    if ck.get("baked") is False:
        warnings.warn(f"{f}: saved before the latent bake (step {ck.get('step')}); its latents are untrained",
                      stacklevel=2)
    model.checkpoint_step = ck.get("step")
    model.checkpoint_config = dict(config)
    return model.to(map_location).train(False)  # NeuralMaterial.eval is the BRDF, not nn.Module.eval
