"""Does training on 4-point footprint targets bias the BrushedMetal's learned BRDF (time-to-quality
history, section 8)? Trains the textured BrushedMetal with ``fast``'s settings at 16, 8 and 4 footprint
points, then compares, per MIP level, each model's f * cos with a 64-point footprint mean of the
reference at 4096 random (uv, wi, wo) rows (half/difference directions, no mollification): the energy
ratio sum(model) / sum(reference) and the mean log-L1 (the training loss).

Run:  OMP_NUM_THREADS=1 python docs/history/footprint_points_bias_probe.py [--points 16,8,4] [--seed 0]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_fidelity import train_and_model  # noqa: E402

from mtlx2neural.contract import ShadingPoint  # noqa: E402
from mtlx2neural.textures.footprint import footprint_targets  # noqa: E402
from mtlx2neural.train.config import preset  # noqa: E402
from mtlx2neural.train.directions import half_difference_pairs  # noqa: E402
from mtlx2neural.train.losses import log_l1  # noqa: E402

ROWS, REFERENCE_POINTS = 4096, 64


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", default="16,8,4")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rows = ["| points | level | energy ratio model / reference | log-L1 |", "|---|---|---|---|"]
    cache = {}
    for k in (int(p) for p in args.points.split(",")):
        ref, stack, model, seconds = train_and_model("BrushedMetal", preset("fast", seed=args.seed, footprint_samples=k))
        print(f"trained {k} points in {seconds:.0f} s", flush=True)
        for level in range(len(stack.levels)):
            if level not in cache:  # the same rows and reference targets for every model
                g = torch.Generator().manual_seed(1000 + level)
                uv = torch.rand(ROWS, 2, generator=g)
                wi, wo = half_difference_pairs(ROWS, g, "cpu")
                lv = torch.full((ROWS,), level, dtype=torch.long)
                with torch.no_grad():
                    target = footprint_targets(ref, stack, wi, wo, uv, lv, REFERENCE_POINTS, g, one_call=True)
                cache[level] = (uv, wi, wo, target)
            uv, wi, wo, target = cache[level]
            with torch.no_grad():
                pred = model.eval(wi, wo, ShadingPoint(uv=uv, lod=torch.full((ROWS,), float(level))))
            ratio = float(pred.sum() / target.sum())
            rows.append(f"| {k} | {level} | {ratio:.3f} | {float(log_l1(pred, target)):.4f} |")
            print(rows[-1], flush=True)
    print("\n".join(rows))


if __name__ == "__main__":
    main()
