"""Time-to-quality levers on the textured GlazedCeramic: HDR FLIP (directional, three views) and
held-out error against training time, per variant and seed (docs/history/time-to-quality-2026-12-03.md).

Run:  OMP_NUM_THREADS=1 python docs/history/time_to_quality_levers.py --seeds 0,1 \
          --variant base:500 --variant one_call:500:footprint_one_call=1 [--out FILE]

A variant is LABEL:ITERATIONS[:FIELD=VALUE,...] on the ``fast`` preset. Each run is trained as
``benchmarks/bench_fidelity.py`` trains (``train_and_model``) and compared by ``render.compare``
(unit sphere, each view's directional light, 96², 32 spp); it prints one Markdown row per run with
the wall and process-CPU seconds of the training alone. The ``footprint_one_call`` switch this page
compared is gone (one call is the only path now); check out commit 8b30aed to rerun that variant.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_fidelity import train_and_model  # noqa: E402

from mtlx2neural.pipeline.material_training import held_out_error  # noqa: E402
from mtlx2neural.render.renderer import compare  # noqa: E402
from mtlx2neural.train.config import TrainConfig, preset  # noqa: E402


def parse_variant(text: str) -> tuple[str, int, dict]:
    label, iters, *rest = text.split(":")
    over = {}
    for item in (rest[0].split(",") if rest and rest[0] else []):
        key, value = item.split("=")
        kind = type(getattr(TrainConfig(), key))
        over[key] = (value in ("1", "true")) if kind is bool else kind(value)
    return label, int(iters), over


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--case", default="GlazedCeramic")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--variant", action="append", required=True)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    head = (f"{os.cpu_count()} cores, torch {torch.__version__}, {torch.get_num_threads()} threads, "
            f"load average {os.getloadavg()[0]:.1f} at start")
    rows = [head, "", "| variant | iterations | seed | train wall s | train CPU s | HDR FLIP (3 views) | mean | held-out |",
            "|---|---|---|---|---|---|---|---|"]
    print("\n".join(rows), flush=True)
    for seed in (int(s) for s in args.seeds.split(",")):
        for text in args.variant:
            label, iters, over = parse_variant(text)
            cfg = preset("fast", iterations=iters, seed=seed, **over)
            c = time.process_time()
            ref, stack, model, wall = train_and_model(args.case, cfg)
            cpu = time.process_time() - c
            flips = [e["flip"] for e in compare(ref, model, texels=tuple(stack.resolution))]
            held = held_out_error(ref, model, stack)
            row = (f"| {label} | {iters} | {seed} | {wall:.0f} | {cpu:.0f} | {', '.join(f'{f:.3f}' for f in flips)} | "
                   f"**{np.mean(flips):.3f}** | {held:.3f} |")
            print(row, flush=True)
            rows.append(row)
            if args.out:
                args.out.write_text("\n".join(rows) + "\n")


if __name__ == "__main__":
    main()
