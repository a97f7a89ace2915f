"""Learned importance sampler versus cosine sampling (and the reference's analytic sampler).

Run:  python benchmarks/bench_sampler.py [--iterations 1000]

Trains each sample material with the ``fast`` preset, then estimates the
directional albedo of the *neural* BRDF (what a renderer using the neural
material integrates) at 16 fixed incoming directions (elevations 0, 30, 60,
80 degrees x 4 azimuths), 4096 samples each, with (a) cosine sampling and
(b) the learned sampler; (c) the reference's own mixture sampler estimating
the reference BRDF is listed for context. Reported: relative variance of the
one-sample estimator and the time to unit relative variance
(``mtlx2neural.verify.sampling_efficiency``).
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
from pathlib import Path

import torch

import mtlx2neural as m2n
from mtlx2neural.textures.parameter_stack import build_parameter_stack
from mtlx2neural.train.config import preset
from mtlx2neural.train.trainer import Trainer
from mtlx2neural.verify.sampling_efficiency import (
    cosine_sample,
    elevation_directions,
    estimator_statistics,
    neural_sample_fn,
)

ROOT = Path(__file__).resolve().parents[1]
CASES = [("Plastic", "/World/Looks/Plastic"), ("CarPaint", "/World/Looks/CarPaint")]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--iterations", type=int)
    args = ap.parse_args()
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads")
    print("| material | sampler | relative variance | us / sample | time to unit rel. variance (us) | "
          "variance ratio cosine / learned |")
    print("|---|---|---|---|---|---|")
    wis = elevation_directions()
    for name, path in CASES:
        ref = m2n.load_reference(ROOT / "samples/layered_spheres.usda", path)
        stack = build_parameter_stack(ref.compiled, resolution=(1, 1))
        model = Trainer(ref, stack, preset("fast", iterations=args.iterations), tempfile.mkdtemp()).run(progress=False)
        cos = estimator_statistics(model.eval, cosine_sample, wis)
        learned = estimator_statistics(model.eval, neural_sample_fn(model), wis)
        analytic = estimator_statistics(ref.eval, lambda wi, u: (lambda s: (s[0], s[2]))(ref.sample(wi, u)), wis)
        ratio = cos["rel_var"] / learned["rel_var"]
        for label, s, r in (("cosine", cos, ""), ("learned (neural proxy)", learned, f"**{ratio:.1f}x**"),
                            ("reference analytic (on the reference BRDF)", analytic, "")):
            print(f"| {name} | {label} | {s['rel_var']:.3f} | {s['seconds_per_sample'] * 1e6:.2f} | "
                  f"{s['time_to_unit_variance'] * 1e6:.3f} | {r} |", flush=True)


if __name__ == "__main__":
    main()
