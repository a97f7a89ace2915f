"""Training throughput (samples/s, data generation included).

Run:  python benchmarks/bench_training.py [--steps 100] [--batch 2048]

Times the trainer on the bundled sample's CarPaint (uniform, standard_surface
with coat over metal) and, when ../shared is present, on wood_tiled (textured,
64x64 latent grid). One "sample" is one (wi, wo, uv, level) query of the BRDF
batch; the sampler batch is extra.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import torch

import mtlx2neural as m2n
from mtlx2neural.textures.parameter_stack import build_parameter_stack
from mtlx2neural.train.config import preset
from mtlx2neural.train.trainer import Trainer

ROOT = Path(__file__).resolve().parents[1]
WOOD = ROOT.parent / "shared/assets/materialx/resources/Materials/Examples/StandardSurface/standard_surface_wood_tiled.mtlx"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--batch", type=int, default=2048)
    args = ap.parse_args()
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads")
    cases = [("sample CarPaint (uniform)", ROOT / "samples/layered_spheres.usda", "/World/Looks/CarPaint", (1, 1))]
    if WOOD.exists():
        cases.append(("wood_tiled (textured, 64x64)", WOOD, None, (64, 64)))
    print("| material | phase mix | steps x batch | samples/s |")
    print("|---|---|---|---|")
    for label, path, mat, res in cases:
        ref = m2n.load_reference(path, mat)
        stack = build_parameter_stack(ref.compiled, resolution=res)
        cfg = preset("fast", iterations=args.steps, batch=args.batch)
        tr = Trainer(ref, stack, cfg, tempfile.mkdtemp())
        t = time.perf_counter()
        tr.run(progress=False)
        dt = time.perf_counter() - t
        print(f"| {label} | encoder {int(cfg.encoder_fraction * 100)}% / fine-tune | {args.steps} x {args.batch} "
              f"| {args.steps * args.batch / dt / 1e3:.1f} k |")


if __name__ == "__main__":
    main()
