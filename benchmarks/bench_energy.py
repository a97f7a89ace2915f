"""Energy and the BRDF loss: HDR FLIP, the energy check's per-level ratios and training time per sample.

Run:  OMP_NUM_THREADS=1 python benchmarks/bench_energy.py --case PolishedMetal --loss log_l1 [--seed 0]
          [--iterations N] [--set FIELD=VALUE ...]

Trains one ``bench_fidelity`` case with the ``fast`` preset (``--loss`` sets ``TrainConfig.brdf_loss``,
``--set`` any other field) and prints one Markdown row: case, loss (and overrides), seed, training
seconds, mean HDR FLIP of ``render.compare`` (unit sphere, three views, 64², 8 spp) and the energy
check (:mod:`mtlx2neural.verify.energy`): the lowest ratio and each MIP level's, finest first.
``PolishedMetal`` needs ``python samples/make_mirror_sample.py`` only if ``samples/mirror`` is gone.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fidelity import CASES, train_and_model  # noqa: E402

from mtlx2neural.export.latents import write_latent_textures  # noqa: E402
from mtlx2neural.formats.latent_codec import latent_bytes_per_texel  # noqa: E402
from mtlx2neural.render.renderer import compare  # noqa: E402
from mtlx2neural.train.config import TrainConfig, preset  # noqa: E402
from mtlx2neural.verify.energy import energy_check  # noqa: E402


def _value(name: str, text: str):
    kind = type(getattr(TrainConfig(), name))
    return text.lower() in ("1", "true", "on") if kind is bool else kind(text)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", required=True, choices=sorted(CASES))
    ap.add_argument("--loss", default="log_l1", help="TrainConfig.brdf_loss")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--iterations", type=int, default=None, help="default: the fast preset's")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="another TrainConfig field")
    args = ap.parse_args()
    fields = {f.name for f in dataclasses.fields(TrainConfig)}
    extra = {}
    for item in args.set:
        name, _, text = item.partition("=")
        if name not in fields:
            ap.error(f"--set {item}: TrainConfig has no field {name}")
        extra[name] = _value(name, text)
    cfg = preset("fast", seed=args.seed, brdf_loss=args.loss, iterations=args.iterations, **extra)
    ref, stack, model, seconds = train_and_model(args.case, cfg)
    check = energy_check(ref, model, tuple(stack.resolution), len(model.latents.levels),
                         params_at=stack.native_params_at())
    with torch.no_grad():
        flip = float(np.mean([e["flip"] for e in compare(ref, model, tuple(stack.resolution), res=64, spp=8)]))
    label = " ".join([args.loss, *args.set])
    levels = " ".join(f"{lv.ratio:.2f}" for lv in check.levels)
    print(f"| {args.case} | {label} | {args.seed} | {seconds:.0f} | {flip:.4f} | {check.min_ratio:.3f} | {levels} |")
    lat = model.latents
    print(f"latents: {lat.latent_format}, {latent_bytes_per_texel(lat.latent_format, lat.channels):g} GPU bytes per "
          f"texel, files {file_bytes(lat)} bytes (half EXR, zip: {file_bytes(lat, exr=True)}), decoded latents' "
          f"PSNR {latent_psnr(lat):.1f} dB")


def file_bytes(latents, exr: bool = False) -> int:
    """Bytes of the exported latent files (all levels): the model's format, or half-float EXR (zip)."""
    with tempfile.TemporaryDirectory() as tmp:
        paths, _ = write_latent_textures(list(latents.levels), tmp, tiles=latents.tile_list,
                                         codec=None if exr else latents.codec)
        return sum(p.stat().st_size for p in Path(tmp).iterdir())


def latent_psnr(latents) -> float:
    """PSNR (dB) of the latents as read (block-decoded) against the trained parameters behind them, over every
    level: 10 log10(peak^2 / MSE) with peak the largest |latent|; inf for uncompressed latents."""
    with torch.no_grad():
        err = sum(float(((latents.level(k) - lv) ** 2).sum()) for k, lv in enumerate(latents.levels))
        n = sum(lv.numel() for lv in latents.levels)
        peak = max(float(lv.abs().max()) for lv in latents.levels)
    return float("inf") if err == 0 else 10 * math.log10(peak * peak / (err / n))


if __name__ == "__main__":
    main()
