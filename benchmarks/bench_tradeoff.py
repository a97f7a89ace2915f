"""The speed-for-accuracy trade: FLIP and evaluations/s for analytic, 2x16, 2x32, 3x64 and the reference.

Run:  python benchmarks/bench_tradeoff.py [--cases Plastic,CarPaint,wood_tiled,GlazedCeramic]
                                          [--analytic-iterations 1000]

Per material (the cases of ``bench_fidelity.py``): the analytic baseline
(Lambert + GGX, 8 fitted channels, ``evaluate.analytic.fit_analytic``) and the
neural model at each decoder size are trained with the ``fast`` preset's
budget, and compared with the reference by ``evaluate.render.compare`` (HDR FLIP,
three views, 96², 32 spp). Evaluations per second are the torch ``eval`` on the
CPU (65,536 random direction pairs at random uv, best of 3, one call each), the
same harness for every model; the generated shaders' own CPU figures are in
``benchmarks/results/shaders_cpu.md`` (``bench_shaders.py``).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np
import torch

from bench_fidelity import CASES, TEXTURED, train_and_model
from mtlx2neural.evaluate.analytic import fit_analytic
from mtlx2neural.evaluate.render import compare
from mtlx2neural.train.config import preset
from mtlx2neural.train.directions import half_difference_pairs


def evals_per_second(fn, n: int = 65536, repeats: int = 3) -> float:
    g = torch.Generator().manual_seed(0)
    wi, wo = half_difference_pairs(n, g)
    uv = torch.rand(n, 2, generator=g)
    best = float("inf")
    with torch.no_grad():
        fn(wi[:1024], wo[:1024], uv[:1024])
        for _ in range(repeats):
            t = time.perf_counter()
            fn(wi, wo, uv)
            best = min(best, time.perf_counter() - t)
    return n / best


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", default="Plastic,CarPaint,wood_tiled,GlazedCeramic")
    ap.add_argument("--analytic-iterations", type=int, default=1000)
    ap.add_argument("--iterations", type=int)
    args = ap.parse_args()
    if not TEXTURED.exists():
        import subprocess
        import sys

        subprocess.run([sys.executable, str(TEXTURED.parents[1] / "make_textured_sample.py")], check=True)
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads")
    print("| material | model | HDR FLIP (mean of 3 views) | torch evals/s (CPU) | speed vs reference |")
    print("|---|---|---|---|---|")
    for name in args.cases.split(","):
        if not CASES[name][0].exists():
            continue
        rows = []
        ref = stack = None
        for dec in ("2x16", "2x32", "3x64"):
            ref, stack, model, _ = train_and_model(name, preset("fast", decoder=dec, iterations=args.iterations))
            flip = np.mean([e["flip"] for e in compare(ref, model, texels=tuple(stack.resolution))])
            rows.append((f"neural {dec}", flip, evals_per_second(lambda a, b, c: model.eval(a, b, c))))
        analytic = fit_analytic(ref, stack, iterations=args.analytic_iterations, batch=4096, seed=0)
        flip = np.mean([e["flip"] for e in compare(ref, analytic, texels=tuple(stack.resolution))])
        rows.insert(0, ("analytic (Lambert + GGX)", flip, evals_per_second(lambda a, b, c: analytic.eval(a, b, c))))
        ref_rate = evals_per_second(lambda a, b, c: ref.eval(a, b, c))
        rows.append(("reference", 0.0, ref_rate))
        for label, f, rate in rows:
            print(f"| {name} | {label} | {f:.3f} | {rate / 1e6:.2f} M | {rate / ref_rate:.2f}x |", flush=True)


if __name__ == "__main__":
    main()
