"""Run every benchmark, one after another, writing each table to ``benchmarks/results/<name>.md``.

Run:  python benchmarks/run_all.py [--only NAME,NAME] [--list]

Benchmarks time things: run on an otherwise idle machine, and compare ratios
within one run (BENCHMARKS.md says where each figure came from). The full set
takes about two hours on a 2-core CPU (the fidelity tables train 18 models).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
# name -> (script, arguments, extra environment)
BENCHMARKS = {
    "reference": ("bench_reference.py", ["--compiled"], {}),
    "textures": ("bench_textures.py", ["--footprint"], {}),
    "training": ("bench_training.py", ["--steps", "30", "--batch", "16384"], {}),
    "step_profile": ("bench_step_profile.py", [], {}),
    "sampler": ("bench_sampler.py", [], {}),
    "fidelity": ("bench_fidelity.py", [], {}),
    "ablation": ("bench_fidelity.py", ["--ablation", "--cases", "GlazedCeramic,BrushedMetal"], {}),
    "tradeoff": ("bench_tradeoff.py", [], {}),
    "lighting": ("bench_lighting.py", ["CarPaint", "GlazedCeramic"], {}),
    "shaders": ("bench_shaders.py", [], {"OMP_NUM_THREADS": "1"}),
    "viewer": ("bench_viewer.py", [], {}),
    "mitsuba": ("bench_mitsuba.py", [], {}),  # needs the mitsuba extra and libLLVM >= 16
    "coat_peak": ("bench_coat_peak.py", [], {}),  # reads MaterialX's car paint from ../shared
    "scene_network": ("bench_scene_network.py", ["samples/scene/glow_and_leaves.usda"], {}),
    "universal": ("bench_universal.py", ["samples/scene/glow_and_leaves.usda"], {}),
}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", help="comma-separated names (default: all)")
    ap.add_argument("--list", action="store_true")
    args = ap.parse_args()
    if args.list:
        for name, (script, argv, env) in BENCHMARKS.items():
            print(f"{name:10s} {script} {' '.join(argv)}")
        return 0
    names = args.only.split(",") if args.only else list(BENCHMARKS)
    out_dir = HERE / "results"
    out_dir.mkdir(exist_ok=True)
    failed = []
    for name in names:
        script, argv, env = BENCHMARKS[name]
        t = time.time()
        print(f"== {name}: {script} {' '.join(argv)}", flush=True)
        with open(out_dir / f"{name}.md", "w") as f:
            rc = subprocess.run([sys.executable, str(HERE / script), *argv], cwd=ROOT, stdout=f,
                                env={**os.environ, **env}).returncode
        print(f"   {'ok' if rc == 0 else f'FAILED ({rc})'} in {time.time() - t:.0f} s -> results/{name}.md", flush=True)
        if rc:
            failed.append(name)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
