"""Fidelity of neural materials (HDR FLIP at three fixed views) per decoder size, and the ablation.

Run:  python benchmarks/bench_fidelity.py [--preset fast] [--decoders 2x16,2x32,3x64] [--cases ...]
      python benchmarks/bench_fidelity.py --ablation [--cases GlazedCeramic,BrushedMetal] [--seeds 1,2]

Each case is trained from scratch with the preset (overridden decoder), exactly
as ``mtlx2neural ASSET`` does, then compared with its reference by
``evaluate.render.compare`` (UV sphere, directional light, the three views of
``render.VIEWS``, 96², 32 spp). ``--ablation`` trains, at equal iterations and
with the 3x64 decoder, the full model, the encoder without learned shading
frames, and a "vanilla" MLP (no frames) on a directly optimised latent texture
(no encoder), as in Table 2 of Zeltner et al. 2024; the no-frame variants get the
paper's extra 8-unit layer (``model.decoder.NO_FRAME_LATENT_LAYER``) to match the
full model's parameter count, and a fourth variant is the full model with the
paper's isotropic sampler (``model.networks.ISOTROPIC_SAMPLER``, its Figure 11). Each
row lists the decoder's and the sampler's parameter counts and the learned
sampler's relative variance (as ``bench_sampler.py``: the neural BRDF's one-sample
albedo estimator, luminance, 16 wi x 4096 samples, here averaged over 4 texels).
Tables go to stdout in Markdown; renders and FLIP maps to
``benchmarks/results/fidelity/``.
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

import mtlx2neural.model.decoder as decoder_module
import mtlx2neural.model.networks as networks_module
from mtlx2neural.contract import ShadingPoint
from mtlx2neural.graph import compile_material
from mtlx2neural.pipeline.material_training import held_out_error
from mtlx2neural.pipeline.plan import latent_resolution
from mtlx2neural.reference import ReferenceMaterial
from mtlx2neural.render.renderer import compare, save_png
from mtlx2neural.scene import find_material
from mtlx2neural.textures.parameter_stack import build_parameter_stack
from mtlx2neural.train.config import preset
from mtlx2neural.train.trainer import Trainer
from mtlx2neural.verify.sampling_efficiency import (
    elevation_directions,
    estimator_statistics,
)

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT.parent / "shared/assets/materialx/resources/Materials/Examples/StandardSurface"
TEXTURED = ROOT / "samples/textured/ceramic_and_metal.usda"
MIRROR = ROOT / "samples/mirror/polished_metal.usda"  # python samples/make_mirror_sample.py
CASES = {
    "Plastic": (ROOT / "samples/layered_spheres.usda", "/World/Looks/Plastic"),
    "CarPaint": (ROOT / "samples/layered_spheres.usda", "/World/Looks/CarPaint"),
    "GlazedCeramic": (TEXTURED, "/World/Looks/GlazedCeramic"),
    "BrushedMetal": (TEXTURED, "/World/Looks/BrushedMetal"),
    "PolishedMetal": (MIRROR, "/World/Looks/PolishedMetal"),
    "wood_tiled": (EXAMPLES / "standard_surface_wood_tiled.mtlx", None),
    "brick_procedural": (EXAMPLES / "standard_surface_brick_procedural.mtlx", None),
}
# label -> (config overrides, extra latent-layer units of a frameless decoder, isotropic sampler)
ABLATION = {
    "full (encoder + 2 frames)": ({}, 0, False),
    "(b) encoder, no frames, + 8-unit layer": ({"frames": 0}, 8, False),
    "(a) vanilla: direct latents, no frames, + 8-unit layer": ({"frames": 0, "encoder_fraction": 0.0}, 8, False),
    "full, isotropic sampler": ({}, 0, True),
}
SAMPLER_TEXELS = ((0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75))
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


def sampler_relative_variance(model) -> float:
    """The learned sampler's relative variance on the neural BRDF (luminance of f * cos / pdf, 16 wi of
    ``elevation_directions`` x 4096 samples), averaged over ``SAMPLER_TEXELS`` (finest level)."""
    out = []
    for uv in SAMPLER_TEXELS:
        at = torch.tensor([uv])

        def eval_fn(wi, wo, at=at):
            return model.eval(wi, wo, ShadingPoint(uv=at.expand(wi.shape[0], 2)))

        def sample_fn(wi, u, at=at):
            return model.sample_direction(wi, u, ShadingPoint(uv=at.expand(wi.shape[0], 2)))

        out.append(estimator_statistics(eval_fn, sample_fn, elevation_directions(), seed=1)["rel_var"])
    return float(np.mean(out))


def ablation_row(name: str, cfg, latent_layer: int, isotropic: bool) -> dict:
    """Train one ablation variant with the measurement-only switches set (and restored after)."""
    before = decoder_module.NO_FRAME_LATENT_LAYER, networks_module.ISOTROPIC_SAMPLER
    decoder_module.NO_FRAME_LATENT_LAYER, networks_module.ISOTROPIC_SAMPLER = latent_layer, isotropic
    try:
        ref, stack, model, seconds = train_and_model(name, cfg)
    finally:
        decoder_module.NO_FRAME_LATENT_LAYER, networks_module.ISOTROPIC_SAMPLER = before
    errors = compare(ref, model, texels=tuple(stack.resolution))
    return {"seconds": seconds, "held_out": held_out_error(ref, model, stack), "flip": [e["flip"] for e in errors],
            "params_decoder": sum(p.numel() for p in model.decoder.parameters()),
            "params_sampler": sum(p.numel() for p in model.sampler.parameters()),
            "rel_var": sampler_relative_variance(model)}


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
    ap.add_argument("--seeds", default="0", help="--ablation: comma-separated training seeds")
    ap.add_argument("--variants", help="--ablation: comma-separated row numbers of ABLATION (0 = full), default all")
    args = ap.parse_args()
    if not TEXTURED.exists():
        subprocess.run([sys.executable, str(ROOT / "samples/make_textured_sample.py")], check=True)
    cases = [c for c in args.cases.split(",") if CASES[c][0].exists()]
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads; preset {args.preset}")
    if args.ablation:
        print("| material | variant | seed | parameters decoder / sampler | train time | held-out log-L1 | "
              "HDR FLIP (3 views) | mean | sampler rel. variance |")
        print("|---|---|---|---|---|---|---|---|---|")
        for name in cases:
            rows = list(ABLATION.items())
            picked = [rows[int(i)] for i in args.variants.split(",")] if args.variants else rows
            for label, (over, latent_layer, isotropic) in picked:
                for seed in (int(s) for s in args.seeds.split(",")):
                    cfg = dataclasses.replace(preset(args.preset, decoder="3x64", iterations=args.iterations,
                                                     seed=seed), **over)
                    r = ablation_row(name, cfg, latent_layer, isotropic)
                    print(f"| {name} | {label} | {seed} | {r['params_decoder']} / {r['params_sampler']} | "
                          f"{r['seconds']:.0f} s | {r['held_out']:.3f} | {', '.join(f'{f:.3f}' for f in r['flip'])} | "
                          f"**{np.mean(r['flip']):.3f}** | {r['rel_var']:.3f} |", flush=True)
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
