"""The speed-for-accuracy trade: FLIP and shader evaluations/s for analytic, 2x16, 2x32, 3x64 and the reference.

Run:  OMP_NUM_THREADS=1 python benchmarks/bench_tradeoff.py
          [--cases Plastic,CarPaint,GlazedCeramic,BrushedMetal,wood_tiled,brick_procedural] [--iterations N]
          [--analytic-iterations N] [--decoders 2x16,2x32,3x64] [--seed N] [--set FIELD=VALUE ...] [--out FILE] [--images DIR]

Per material (the cases of ``bench_fidelity.py``: the four project samples and two textured
MaterialX examples), the analytic baseline (Lambert + GGX, 8 fitted channels,
``evaluate.analytic.fit_analytic``, 1000 steps) and the neural model at each decoder size
(``fast`` preset) are trained, then:

- **FLIP**: mean HDR FLIP against the reference over the three fixed views (sphere, 96²),
  under the procedural sky (``EnvironmentMap.sky``, 64 spp: the whole lobe is lit at once, as in
  a renderer; light samples and the reference's BSDF samples combined by MIS, shared by every
  model) and under each view's directional light (32 spp: one highlight per point);
  one reference render per view and lighting, shared by the models (``render.compare_many``).
- **Shader evals/s**, every model in the same harness, slangpy's CPU device
  (``evaluate.shader_cost.shader_rates``): MaterialX's own generated Slang for the reference,
  the generated FP32 modules for the neural models and ``codegen/slang/AnalyticMaterial.slang``
  for the analytic baseline, the last two fetching their pyramids. Best of 3 dispatches of
  16,384 random (uv, lod, wi, wo) queries.
- torch ``eval`` throughput (65,536 queries) for reference: not the product.

``--timing-only`` skips training and FLIP and times the shaders alone, with seeded weights and
latents on each material's latent grid (a shader's cost does not depend on the values): a
quick run for an otherwise idle machine, whose ratios are the ones to quote.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fidelity import CASES, TEXTURED, train_and_model

from mtlx2neural.baseline.analytic_model import fit_analytic
from mtlx2neural.render.lighting import EnvironmentMap
from mtlx2neural.render.renderer import compare_many, save_png
from mtlx2neural.report.shader_cost import best_time, random_queries, shader_rates
from mtlx2neural.scene import find_material
from mtlx2neural.train.config import TrainConfig, preset

DECODERS = ("2x16", "2x32", "3x64")


def torch_rate(fn, n: int = 65536) -> float:
    wi, wo, uv = (torch.from_numpy(a) for a in random_queries(n, 1)[:3])
    with torch.no_grad():
        return n / best_time(lambda: fn(wi, wo, uv))


def timing_only(names: list[str]) -> list[str]:
    """The shader columns alone, untrained models on each case's latent grid (module docstring)."""
    from mtlx2neural.baseline.analytic_model import AnalyticMaterial
    from mtlx2neural.graph import compile_material
    from mtlx2neural.model.neural_material import NeuralMaterial
    from mtlx2neural.pipeline.convert import latent_resolution

    lines = ["| material | latent grid | model | shader evals/s | vs reference |", "|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for name in names:
        src = find_material(*CASES[name])
        grid = latent_resolution(compile_material(src.document, src.material), preset("fast"))
        torch.manual_seed(0)
        models = {d: NeuralMaterial(grid, in_dim=0, decoder=d) for d in DECODERS}
        analytic = AnalyticMaterial(grid)
        with torch.no_grad():
            for lv in analytic.maps.levels:
                lv.normal_(0, 1)
        rates = shader_rates(models, analytic, src)
        for key in ("analytic", *DECODERS, "reference"):
            r, ref = rates[key], rates["reference"]
            label = {"analytic": "analytic (Lambert + GGX)", "reference": "reference (MaterialX Slang)"}.get(
                key, f"neural {key}")
            row = (f"| {name} | {grid[1]}x{grid[0]} | {label} | {f'{r / 1e6:.3f} M' if r else '-'} | "
                   f"{f'{r / ref:.2f}x' if r and ref else '-'} |")
            print(row, flush=True)
            lines.append(row)
    return lines


def config_overrides(items: list[str], ap: argparse.ArgumentParser) -> dict:
    """``FIELD=VALUE`` strings as TrainConfig overrides, each value parsed as its field's type."""
    own_flags = {"decoder", "iterations", "seed"}  # --decoders, --iterations, --seed
    fields = [f.name for f in dataclasses.fields(TrainConfig) if f.name not in own_flags]
    defaults = TrainConfig()
    out = {}
    for item in items:
        key, _, value = item.partition("=")
        if key not in fields or not value:
            ap.error(f"--set {item}: expected FIELD=VALUE with FIELD one of {', '.join(fields)} "
                     f"({', '.join(sorted(own_flags))} have flags of their own)")
        default = getattr(defaults, key)
        kind = type(default) if default is not None else int
        out[key] = (value.lower() in ("1", "true", "yes")) if kind is bool else kind(value)
    return out


def save_strip(path: Path, results: dict, neural: str = "3x64") -> None:
    """One row per view: reference | analytic | its FLIP map | neural ``neural`` | its FLIP map."""
    rows = []
    for a, n in zip(results["analytic"], results[neural]):
        rows.append(np.concatenate([a["reference"], a["analytic"], a["flip_map"] ** 2.2,
                                    n[neural], n["flip_map"] ** 2.2], 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    save_png(path, np.concatenate(rows))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", default="Plastic,CarPaint,GlazedCeramic,BrushedMetal,wood_tiled,brick_procedural")
    ap.add_argument("--analytic-iterations", type=int, default=1000)
    ap.add_argument("--iterations", type=int, help="training steps of the neural models (default: the preset's)")
    ap.add_argument("--decoders", default=",".join(DECODERS),
                    help="neural sizes to train (3x64 is the one the analytic ratio is quoted against)")
    ap.add_argument("--seed", type=int, default=0, help="seed of every training and of the analytic fit")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                    help="override a TrainConfig field of the fast preset (a sweep), e.g. level_rate=0.5")
    ap.add_argument("--out", type=Path, help="also write the table (Markdown) here")
    ap.add_argument("--images", type=Path, help="write per-material render strips (PNG) into this folder")
    ap.add_argument("--timing-only", action="store_true", help="shader evals/s only, no training (docstring)")
    args = ap.parse_args()
    if not TEXTURED.exists():
        import subprocess

        subprocess.run([sys.executable, str(TEXTURED.parents[1] / "make_textured_sample.py")], check=True)
    if args.timing_only:
        head = (f"machine: {platform.machine()}, {os.cpu_count()} cores, OMP_NUM_THREADS="
                f"{os.environ.get('OMP_NUM_THREADS', '-')}; slangpy CPU device, FP32, 16,384 queries, best of 3")
        print(head)
        lines = [head, ""] + timing_only([c for c in args.cases.split(",") if CASES[c][0].exists()])
        if args.out:
            args.out.write_text("\n".join(lines) + "\n")
        return
    lines = [f"machine: {platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}, "
             f"{torch.get_num_threads()} threads; fast preset"
             + (f", {args.iterations} iterations" if args.iterations else "") + f", seed {args.seed}"
             + "".join(f", {o}" for o in args.set)
             + f"; analytic fit {args.analytic_iterations} iterations", "",
             "| material | model | FLIP, sky | FLIP, directional | shader evals/s | vs reference | torch evals/s |",
             "|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    sky = [EnvironmentMap.sky()]
    decoders = tuple(d for d in DECODERS if d in args.decoders.split(","))
    if not decoders:
        ap.error(f"--decoders: choose from {', '.join(DECODERS)}")
    largest = decoders[-1]
    overrides = config_overrides(args.set, ap)
    for name in args.cases.split(","):
        if not CASES[name][0].exists():
            print(f"  ({name}: {CASES[name][0]} is missing; skipped)", file=sys.stderr)
            continue
        models = {}
        for dec in decoders:
            cfg = preset("fast", decoder=dec, iterations=args.iterations, seed=args.seed, **overrides)
            ref, stack, models[dec], _ = train_and_model(name, cfg)
        analytic = fit_analytic(ref, stack, iterations=args.analytic_iterations, batch=4096, seed=args.seed)
        everything = {"analytic": analytic, **models}
        texels = tuple(stack.resolution)
        flips = {}
        for light, kw in (("sky", {"lights": sky, "spp": 64}), ("directional", {"spp": 32})):
            results = compare_many(ref, everything, texels, **kw)
            for label, errs in results.items():
                flips[label, light] = float(np.mean([e["flip"] for e in errs]))
            if args.images:
                save_strip(args.images / f"{name}_{light}.png", results, largest)
        shader = shader_rates(models, analytic, find_material(*CASES[name]))
        ref_torch = torch_rate(ref.eval)
        rows = [("analytic", "analytic (Lambert + GGX)")] + [(d, f"neural {d}") for d in decoders] + \
            [("reference", "reference")]
        for key, label in rows:
            m = everything.get(key)
            rate = shader[key]
            speed = f"{rate / shader['reference']:.2f}x" if rate and shader["reference"] else "-"
            tr = ref_torch if m is None else torch_rate(m.eval)
            sky_f, dir_f = (flips.get((key, "sky"), 0.0), flips.get((key, "directional"), 0.0))
            row = (f"| {name} | {label} | {sky_f:.3f} | {dir_f:.3f} | "
                   f"{f'{rate / 1e6:.2f} M' if rate else '-'} | {speed} | {tr / 1e6:.2f} M |")
            print(row, flush=True)
            lines.append(row)
        ratio = [flips["analytic", lt] / flips[largest, lt] for lt in ("sky", "directional")]
        note = f"  {name}: analytic / {largest} FLIP = {ratio[0]:.2f}x (sky), {ratio[1]:.2f}x (directional)"
        print(note, flush=True)
        lines.append(f"<!-- {note.strip()} -->")
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
