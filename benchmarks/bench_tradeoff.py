"""The speed-for-accuracy trade: FLIP and shader evaluations/s for analytic, 2x16, 2x32, 3x64 and the reference.

Run:  OMP_NUM_THREADS=1 python benchmarks/bench_tradeoff.py
          [--cases Plastic,CarPaint,GlazedCeramic,wood_tiled,brass_tiled] [--iterations N] [--out FILE]

Per material (the cases of ``bench_fidelity.py``: the project samples and two textured
MaterialX examples), the analytic baseline (Lambert + GGX, 8 fitted channels,
``evaluate.analytic.fit_analytic``, 1000 steps) and the neural model at each decoder size
(``fast`` preset) are trained, then:

- **FLIP**: mean HDR FLIP against the reference over the three fixed views (sphere, 96²),
  under the procedural sky (``EnvironmentMap.sky``, 64 spp: the whole lobe is lit at once, as in
  a renderer) and under each view's directional light (32 spp: one highlight per point);
  one reference render per view and lighting, shared by the models (``render.compare_many``).
- **Shader evals/s**, every model in the same harness, slangpy's CPU device: the reference is
  MaterialX's own generated Slang for the material (``evaluate.mtlx_oracle``; it shades twice
  per query, lit and unlit, so its rate is doubled, and samples its textures at one uv); the
  neural models are their generated FP32 modules and the analytic baseline
  ``codegen/slang/AnalyticMaterial.slang``, each fetching its latent/channel pyramid (stochastic
  level, bilinear) and evaluating in one thread (``fetch_eval``). Best of 3 dispatches of
  16,384 random (uv, lod, wi, wo) queries, buffer uploads included for all.
- torch ``eval`` throughput (65,536 queries) for reference: not the product.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fidelity import CASES, TEXTURED, train_and_model  # noqa: E402
from mtlx2neural.evaluate.analytic import fit_analytic  # noqa: E402
from mtlx2neural.evaluate.lighting import EnvironmentMap  # noqa: E402
from mtlx2neural.evaluate.render import compare_many  # noqa: E402
from mtlx2neural.train.config import preset  # noqa: E402
from mtlx2neural.train.directions import half_difference_pairs  # noqa: E402

DECODERS = ("2x16", "2x32", "3x64")


def best_of(fn, repeats: int = 3) -> float:
    fn()  # warm-up (and compilation)
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def queries(n: int, levels: int, seed: int = 0):
    """(wi, wo, uv, lod, u) float32 NumPy: directions uniform in half/difference angles."""
    g = torch.Generator().manual_seed(seed)
    wi, wo = half_difference_pairs(n, g)
    uv = torch.rand(n, 2, generator=g)
    lod = torch.rand(n, generator=g) * max(levels - 1, 0)
    u = torch.rand(n, generator=g)
    return [t.numpy().astype(np.float32) for t in (wi, wo, uv, lod, u)]


def torch_rate(fn, n: int = 65536) -> float:
    wi, wo, uv, _, _ = (torch.from_numpy(a) for a in queries(n, 1))
    with torch.no_grad():
        return n / best_of(lambda: fn(wi, wo, uv))


def shader_rates(name: str, models: dict, analytic, n: int = 16384) -> dict:
    """Evaluations/s per label in the slangpy CPU harness (module docstring); None if unavailable."""
    from mtlx2neural.codegen import generate_slang
    from mtlx2neural.codegen.analytic import CpuAnalytic, decoded_levels
    from mtlx2neural.codegen.cpu import CpuMaterial, slangpy_available
    from mtlx2neural.codegen.spec import as_spec
    from mtlx2neural.evaluate.mtlx_oracle import OracleError, mtlx_slang_eval, oracle_available
    from mtlx2neural.scene import find_material

    rates = dict.fromkeys(["reference", "analytic", *models], None)
    if not slangpy_available()[0]:
        return rates
    for label, model in models.items():
        levels = [lv.detach().numpy() for lv in model.latents.levels]
        wi, wo, uv, lod, u = queries(n, len(levels))
        cm = CpuMaterial(generate_slang(model, f"Trade{label}"), f"Trade{label}", as_spec(model), "FP32")
        pyr = cm.pyramid(levels)
        rates[label] = n / best_of(lambda cm=cm, pyr=pyr: cm.fetch_eval(pyr, uv, lod, u, wi, wo))
    am = CpuAnalytic()
    levels = decoded_levels(analytic)
    wi, wo, uv, lod, u = queries(n, len(levels))
    pyr = am.pyramid(levels)
    rates["analytic"] = n / best_of(lambda: am.fetch_eval(pyr, uv, lod, u, wi, wo))
    if oracle_available()[0]:
        src = find_material(*CASES[name])
        try:
            rates["reference"] = 2 * n / best_of(lambda: mtlx_slang_eval(src.document, src.material, wi, wo))
        except OracleError as exc:
            print(f"  ({name}: MaterialX oracle unavailable: {exc})", file=sys.stderr)
    return rates


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", default="Plastic,CarPaint,GlazedCeramic,wood_tiled,brass_tiled")
    ap.add_argument("--analytic-iterations", type=int, default=1000)
    ap.add_argument("--iterations", type=int, help="training steps of the neural models (default: the preset's)")
    ap.add_argument("--out", type=Path, help="also write the table (Markdown) here")
    args = ap.parse_args()
    if not TEXTURED.exists():
        import subprocess

        subprocess.run([sys.executable, str(TEXTURED.parents[1] / "make_textured_sample.py")], check=True)
    lines = [f"machine: {platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}, "
             f"{torch.get_num_threads()} threads; fast preset"
             + (f", {args.iterations} iterations" if args.iterations else ""), "",
             "| material | model | FLIP, sky | FLIP, directional | shader evals/s | vs reference | torch evals/s |",
             "|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    sky = [EnvironmentMap.sky()]
    for name in args.cases.split(","):
        if not CASES[name][0].exists():
            print(f"  ({name}: {CASES[name][0]} is missing; skipped)", file=sys.stderr)
            continue
        models = {}
        for dec in DECODERS:
            ref, stack, models[dec], _ = train_and_model(name, preset("fast", decoder=dec, iterations=args.iterations))
        analytic = fit_analytic(ref, stack, iterations=args.analytic_iterations, batch=4096, seed=0)
        everything = {"analytic": analytic, **models}
        texels = tuple(stack.resolution)
        flips = {}
        for light, kw in (("sky", {"lights": sky, "spp": 64}), ("directional", {"spp": 32})):
            for label, errs in compare_many(ref, everything, texels, **kw).items():
                flips[label, light] = float(np.mean([e["flip"] for e in errs]))
        shader = shader_rates(name, models, analytic)
        ref_torch = torch_rate(lambda a, b, c: ref.eval(a, b, c))
        rows = [("analytic", "analytic (Lambert + GGX)")] + [(d, f"neural {d}") for d in DECODERS] + \
            [("reference", "reference")]
        for key, label in rows:
            m = everything.get(key)
            rate = shader[key]
            speed = f"{rate / shader['reference']:.2f}x" if rate and shader["reference"] else "-"
            tr = ref_torch if m is None else torch_rate(lambda a, b, c, m=m: m.eval(a, b, c))
            sky_f, dir_f = (flips.get((key, "sky"), 0.0), flips.get((key, "directional"), 0.0))
            row = (f"| {name} | {label} | {sky_f:.3f} | {dir_f:.3f} | "
                   f"{f'{rate / 1e6:.2f} M' if rate else '-'} | {speed} | {tr / 1e6:.2f} M |")
            print(row, flush=True)
            lines.append(row)
        ratio = [flips["analytic", lt] / flips["3x64", lt] for lt in ("sky", "directional")]
        note = f"  {name}: analytic / 3x64 FLIP = {ratio[0]:.2f}x (sky), {ratio[1]:.2f}x (directional)"
        print(note, flush=True)
        lines.append(f"<!-- {note.strip()} -->")
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
