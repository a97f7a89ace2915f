"""Fidelity of neural materials (HDR FLIP at three fixed views) per decoder size, and the ablation.

Run:  python benchmarks/bench_fidelity.py [--preset fast] [--decoders 2x16,2x32,3x64] [--cases ...]
      python benchmarks/bench_fidelity.py --ablation [--cases GlazedCeramic]

Each case is trained from scratch with the preset (overridden decoder), exactly
as ``mtlx2neural ASSET`` does, then compared with its reference by
``evaluate.render.compare`` (UV sphere, directional light, the three views of
``render.VIEWS``, 96², 32 spp). ``--ablation`` trains, at equal iterations and
with the 3x64 decoder, the full model, the encoder without learned shading
frames, and a "vanilla" MLP (no frames) on a directly optimised latent texture
(no encoder), as in Table 2 of Zeltner et al. 2024. Tables go to stdout in
Markdown; renders and FLIP maps to ``benchmarks/results/fidelity/``.
Run on an otherwise idle machine: times are wall-clock.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from mtlx2neural.graph import compile_material
from mtlx2neural.pipeline.convert import held_out_error, latent_resolution
from mtlx2neural.reference import ReferenceMaterial
from mtlx2neural.render.renderer import compare, save_png
from mtlx2neural.scene import find_material
from mtlx2neural.textures.parameter_stack import build_parameter_stack
from mtlx2neural.train.config import preset
from mtlx2neural.train.trainer import Trainer

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT.parent / "shared/assets/materialx/resources/Materials/Examples/StandardSurface"
TEXTURED = ROOT / "samples/textured/ceramic_and_metal.usda"
CASES = {
    "Plastic": (ROOT / "samples/layered_spheres.usda", "/World/Looks/Plastic"),
    "CarPaint": (ROOT / "samples/layered_spheres.usda", "/World/Looks/CarPaint"),
    "GlazedCeramic": (TEXTURED, "/World/Looks/GlazedCeramic"),
    "BrushedMetal": (TEXTURED, "/World/Looks/BrushedMetal"),
    "wood_tiled": (EXAMPLES / "standard_surface_wood_tiled.mtlx", None),
    "brick_procedural": (EXAMPLES / "standard_surface_brick_procedural.mtlx", None),
}
ABLATION = {
    "full (encoder + 2 frames)": {},
    "(b) encoder, no frames": {"frames": 0},
    "(a) vanilla: direct latents, no frames": {"frames": 0, "encoder_fraction": 0.0},
}
OUT = ROOT / "benchmarks/results/fidelity"


def train_and_model(name: str, cfg):
    """Compile case ``name``, build its stack and train it: (reference, stack, model, seconds)."""
    asset, material = CASES[name]
    src = find_material(asset, material)
    compiled = compile_material(src.document, src.material)
    ref = ReferenceMaterial(compiled)
    stack = build_parameter_stack(compiled, resolution=latent_resolution(compiled, cfg))
    t = time.perf_counter()
    model = Trainer(ref, stack, cfg, tempfile.mkdtemp()).run(progress=False)
    return ref, stack, model, time.perf_counter() - t


def train_and_measure(name: str, cfg) -> dict:
    ref, stack, model, seconds = train_and_model(name, cfg)
    errors = compare(ref, model, texels=tuple(stack.resolution))
    tag = f"{name}_{cfg.decoder}_f{cfg.frames}_e{cfg.encoder_fraction:g}"
    OUT.mkdir(parents=True, exist_ok=True)
    strip = np.concatenate([np.concatenate([e["reference"], e["neural"], e["flip_map"] ** 2.2], 1) for e in errors])
    save_png(OUT / f"{tag}.png", strip)
    return {"seconds": seconds, "held_out": held_out_error(ref, model, stack),
            "flip": [e["flip"] for e in errors], "res": stack.resolution}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--decoders", default="2x16,2x32,3x64")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--iterations", type=int)
    ap.add_argument("--ablation", action="store_true")
    args = ap.parse_args()
    if not TEXTURED.exists():
        subprocess.run([sys.executable, str(ROOT / "samples/make_textured_sample.py")], check=True)
    cases = [c for c in args.cases.split(",") if CASES[c][0].exists()]
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads; preset {args.preset}")
    if args.ablation:
        print("| material | variant | train time | held-out log-L1 | HDR FLIP (3 views) | mean |")
        print("|---|---|---|---|---|---|")
        for name in cases:
            for label, over in ABLATION.items():
                cfg = dataclasses.replace(preset(args.preset, decoder="3x64", iterations=args.iterations), **over)
                r = train_and_measure(name, cfg)
                print(f"| {name} | {label} | {r['seconds']:.0f} s | {r['held_out']:.3f} | "
                      f"{', '.join(f'{f:.3f}' for f in r['flip'])} | **{np.mean(r['flip']):.3f}** |", flush=True)
        return
    print("| material | latent grid | decoder | train time | held-out log-L1 | HDR FLIP (3 views) | mean |")
    print("|---|---|---|---|---|---|---|")
    for name in cases:
        for dec in args.decoders.split(","):
            r = train_and_measure(name, preset(args.preset, decoder=dec, iterations=args.iterations))
            print(f"| {name} | {r['res'][1]}x{r['res'][0]} | {dec} | {r['seconds']:.0f} s | {r['held_out']:.3f} | "
                  f"{', '.join(f'{f:.3f}' for f in r['flip'])} | **{np.mean(r['flip']):.3f}** |", flush=True)


if __name__ == "__main__":
    main()
