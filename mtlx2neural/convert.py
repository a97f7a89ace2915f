"""``mtlx2neural ASSET``: train a neural material for every material the scene selects, then export.

For each material: compile the reference, build the parameter pyramid (capped
at the preset's resolution), train, and write into ``OUT/<material>/``:
``checkpoint.pt`` (model, optimiser, config), ``training_curves.csv``,
``summary.json`` (settings, source hash, time, held-out error, HDR FLIP at three
views) and PNG renders of reference, neural model and FLIP map per view. A
material whose ``summary.json`` carries the same source hash (MaterialX document,
texture bytes, training settings: :mod:`.export.cache`) is not trained again; its
checkpoint is reused (``force`` retrains). Then everything is exported
(:mod:`.export.bundle`): latent EXRs and FP16 weights into ``OUT/<material>/neural/``
and the neural USD layer ``OUT.parent/<OUT name>.usda``. ``OUT`` defaults to
``<asset folder>/<asset stem>_neural``; the input is never modified.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import platform
import re
import time
from pathlib import Path

import torch

from .errors import InputError
from .evaluate.render import compare, save_png
from .export import export_asset, source_hash
from .export.cache import cached_summary
from .export.usd_writer import register_schema
from .graph import compile_material
from .model.checkpoint import load_checkpoint
from .reference import ReferenceMaterial
from .scene import load_asset
from .textures.footprint import footprint_targets
from .textures.parameter_stack import build_parameter_stack, texture_resolution
from .train.config import PRESETS, TrainConfig
from .train.directions import half_difference_pairs
from .train.losses import log_l1
from .train.trainer import Trainer


def default_output(asset) -> Path:
    asset = Path(asset).resolve()
    return asset.parent / f"{asset.stem}_neural"


def material_folder(name: str) -> str:
    """A file-system-safe folder name for a material path or name."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name.strip("/")) or "material"


def resolve_device(device: str) -> str:
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    return device


def latent_resolution(compiled, cfg: TrainConfig) -> tuple[int, int]:
    """The latent grid for ``compiled``: (1, 1) for a uniform material, else the textures'
    texel grid scaled down to ``cfg.max_resolution`` texels per side."""
    if not compiled.varying_parameters():
        return (1, 1)
    h, w, _ = texture_resolution(compiled)
    if cfg.max_resolution:
        s = min(1.0, cfg.max_resolution / max(h, w))
        h, w = max(1, int(h * s)), max(1, int(w * s))
    return (h, w)


def held_out_error(ref: ReferenceMaterial, model, stack, n: int = 8192, seed: int = 12345) -> float:
    """Log-L1 between the neural model at level 0 and the reference averaged over a level-0
    texel's footprint (the training target, up to 64 points), uv uniform, half/difference
    directions, on draws the training never saw."""
    g = torch.Generator().manual_seed(seed)
    wi, wo = half_difference_pairs(n, g)
    uv = torch.rand(n, 2, generator=g)
    level = torch.zeros(n, dtype=torch.long)
    with torch.no_grad():
        target = footprint_targets(ref, stack, wi, wo, uv, level, 64, g) if stack.channels else ref.eval(wi, wo)
        return float(log_l1(model.eval(wi, wo, uv), target))


def preset_name(cfg: TrainConfig) -> str:
    """The preset ``cfg`` equals, else "custom"."""
    return next((name for name, p in PRESETS.items() if p == cfg), "custom")


def device_name(device: str) -> str:
    """``cpu (x86_64)`` or ``cuda:0 (<GPU name>)``: where the training ran, for the metrics."""
    if device.startswith("cuda") and torch.cuda.is_available():
        d = torch.device(device)
        return f"cuda:{d.index or 0} ({torch.cuda.get_device_name(d)})"
    return f"{device} ({platform.machine() or 'unknown'})"


def _select(scene, asset, material):
    sources = [s for s in scene.materials
               if material is None or material in (s.name, s.name.rsplit("/", 1)[-1], s.material)]
    if not sources and material is not None:
        from .scene import find_material

        sources = [find_material(asset, material)]  # an explicitly named material, even if unbound
    if not sources:
        choices = [s.name for s in scene.materials] + [f"{n} (skipped: {why})" for n, why in scene.skipped]
        what = f"no material named '{material}'" if material else "no material bound to renderable geometry"
        raise InputError(f"{scene.asset}: {what}. Materials: {', '.join(choices) or 'none'}. "
                         f"Name one with --material.")
    return sources


def train_material(src, cfg: TrainConfig, folder: Path, device: str, resume: bool, progress: bool,
                   allow_missing_textures: bool, digest: str):
    """Train one material into ``folder``; returns (model, summary) and writes ``summary.json``."""
    t0 = time.time()
    # An interrupted run must not leave an old summary (and its hash) beside a new checkpoint.
    (folder / "summary.json").unlink(missing_ok=True)
    compiled = compile_material(src.document, src.material, device=device,
                                allow_missing_textures=allow_missing_textures)
    ref = ReferenceMaterial(compiled)
    stack = build_parameter_stack(compiled, resolution=latent_resolution(compiled, cfg))
    trainer = Trainer(ref, stack, cfg, folder, device=device)
    if resume:
        trainer.resume()
    if progress:
        print(f"{src.name}: {stack.resolution[1]}x{stack.resolution[0]} latent grid, "
              f"{stack.levels[0].shape[0]} varying channels, preset {cfg.iterations} steps x {cfg.batch}")
    model = trainer.run(progress=progress)
    train_seconds = time.time() - t0
    errors = compare(ref, model, texels=tuple(stack.resolution))
    for i, e in enumerate(errors):
        save_png(folder / f"view{i}_reference.png", e["reference"])
        save_png(folder / f"view{i}_neural.png", e["neural"])
        save_png(folder / f"view{i}_flip.png", e["flip_map"], linear=False)
    summary = {"material": src.name, "mtlx_material": src.material, "source": src.source_file,
               "bound_prims": list(src.bound_prims), "source_hash": digest,
               "resolution": list(stack.resolution), "varying_channels": int(stack.levels[0].shape[0]),
               "config": dataclasses.asdict(cfg),
               "steps": trainer.step, "seconds": round(time.time() - t0, 1),
               "train_seconds": round(train_seconds, 2),
               "final_loss_brdf": trainer.history[-1]["loss_brdf"] if trainer.history else math.nan,
               "held_out_log_l1": held_out_error(ref, model, stack), "device": device,
               "device_name": device_name(device),
               "flip_per_view": [round(e["flip"], 4) for e in errors],
               "flip_mean": round(float(sum(e["flip"] for e in errors) / len(errors)), 4),
               "relmse_mean": round(float(sum(e["relmse"] for e in errors) / len(errors)), 5),
               "notes": stack.notes}
    tmp = folder / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=2))
    os.replace(tmp, folder / "summary.json")
    return model, summary


def _reuse(folder: Path, digest: str):
    """(model, summary) of an earlier run of the same source hash in ``folder``, or None."""
    summary = cached_summary(folder, digest)
    if summary is None:
        return None
    try:
        model = load_checkpoint(folder)
    except InputError:  # unreadable: train again
        return None
    return (model, summary) if model.checkpoint_step == summary.get("steps") else None


def convert_asset(asset, cfg: TrainConfig, out=None, material: str | None = None, device: str = "cpu",
                  resume: bool = False, progress: bool = True, allow_missing_textures: bool = False,
                  force: bool = False, preset: str | None = None, usda=None) -> list[dict]:
    """Train (or reuse) every selected material (or only ``material``), then export them.

    Returns one summary per material, with ``cached`` (True: reused, nothing trained),
    ``usd`` (the layer written) and ``export_notes`` (FP16 range-check notes) added.
    ``preset`` names the preset for ``neural:metrics:preset`` (default: the preset
    ``cfg`` equals, else "custom"); ``usda`` overrides the layer's path.
    """
    register_schema()  # before USD's schema registry is first built
    scene = load_asset(asset)
    out = Path(out) if out else default_output(asset)
    sources = _select(scene, asset, material)
    device = resolve_device(device)
    trained, summaries = [], []
    for src in sources:
        folder = out / material_folder(src.name)
        digest = source_hash(src, cfg, allow_missing_textures)
        reused = None if force else _reuse(folder, digest)
        cached = reused is not None
        if cached:
            model, summary = reused
            if progress:
                print(f"{src.name}: unchanged since the last run (source hash {digest[:12]}): reusing {folder}")
        else:
            model, summary = train_material(src, cfg, folder, device, resume, progress,
                                            allow_missing_textures, digest)
        summary = {**summary, "cached": cached}
        trained.append((model, summary, folder))
        summaries.append(summary)
    layer, exported = export_asset(scene.asset, trained, out, preset or preset_name(cfg), usda)
    for s, e in zip(summaries, exported):
        s["usd"], s["export_notes"] = str(layer), e.notes
    return summaries
