"""What training through the block decoder costs: seconds per step after the bake, with and without it.

Run:  OMP_NUM_THREADS=1 python benchmarks/bench_latent_codec.py [--case BrushedMetal] [--steps 20] [--rounds 3]

Builds one ``bench_fidelity`` case's trainer with the ``fast`` preset, bakes its latents (the encoder
phase is skipped: the step cost does not depend on the weights), then times ``--steps`` training steps
per format, the formats interleaved over ``--rounds`` rounds (A/B/C/A/B/C..., so the machine's load
hits each alike), and prints the median seconds per step of each format and its ratio to ``exr``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fidelity import CASES, compile_material, find_material, latent_resolution  # noqa: E402

from mtlx2neural.formats.latent_codec import FORMATS, LatentCodec  # noqa: E402
from mtlx2neural.reference import ReferenceMaterial  # noqa: E402
from mtlx2neural.textures.parameter_stack import build_parameter_stack  # noqa: E402
from mtlx2neural.train.config import preset  # noqa: E402
from mtlx2neural.train.trainer import Trainer  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", default="BrushedMetal", choices=sorted(CASES))
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    asset, material = CASES[args.case]
    src = find_material(asset, material)
    compiled = compile_material(src.document, src.material)
    cfg = preset("fast")
    stack = build_parameter_stack(compiled, resolution=latent_resolution(compiled, cfg))
    trainer = Trainer(ReferenceMaterial(compiled), stack, cfg, tempfile.mkdtemp())
    trainer.bake()
    latents = trainer.model.latents
    codecs = {name: None if fmt is None else LatentCodec(name, latents.channels) for name, fmt in FORMATS.items()}
    for codec in codecs.values():
        if codec is not None:
            codec.fit(list(latents.levels))
    times: dict[str, list[float]] = {name: [] for name in codecs}
    for _ in range(args.rounds):
        for name, codec in codecs.items():
            latents.codec = codec
            t = time.perf_counter()
            for _ in range(args.steps):
                trainer.train_step()
            times[name].append((time.perf_counter() - t) / args.steps)
    base = statistics.median(times["exr"])
    print(f"{args.case}, latent grid {latents.resolution}, {latents.num_levels} levels, {args.steps} steps x "
          f"{args.rounds} rounds")
    for name, ts in times.items():
        med = statistics.median(ts)
        print(f"| {name} | {med * 1000:.0f} ms | {med / base:.2f}x |")


if __name__ == "__main__":
    main()
