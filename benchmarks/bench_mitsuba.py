"""Mitsuba 3: the neural and the reference material in a path tracer we did not write.

Run:  python benchmarks/bench_mitsuba.py [--asset samples/scene/glow_and_leaves.usda] [--layer LAYER]
          [--decoders 2x16,2x32,3x64] [--iterations 200] [--res 128] [--spp 16]

Prints Markdown tables:

1. **Time per sample.** The asset's whole stage (every material on its meshes, the stage's camera and
   lights; :func:`mtlx2neural.mitsuba.render.render_stage`'s scene) rendered by Mitsuba's ``path``
   integrator (``max_depth`` 3) with every material bound to ``mtlx_reference`` and then, for each decoder
   size, to ``mtlx_neural``. Each configuration renders twice with the same seed and the second render is
   timed (the first compiles Dr.Jit's kernels): microseconds per sample (seconds / (res^2 x spp)) and the
   neural-to-reference ratio, all in one process, so the ratio is the figure to quote. The neural models for
   the timing are short ``fast`` trainings (``--iterations``; the cost of a decoder does not depend on its
   weights), one conversion per decoder size into a temporary folder.
2. **Fidelity in Mitsuba** of ``--layer`` (default: the asset's ``fast`` conversion beside it, made first
   when missing): per converted material, :func:`mtlx2neural.mitsuba.render.in_scene_flip` (HDR FLIP of
   ``mtlx_neural`` against ``mtlx_reference`` on the material's own meshes) beside the record's
   ``flip_in_scene`` (the torch renderer's), and a white furnace: the directional albedo each plugin's own
   ``sample`` gives in Mitsuba (mean of the sample weights, 4096 samples at each of 16 seeded uvs where the
   material is there, x 3 view angles, 0, 45 and 75 degrees), neural over reference.
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mtlx2neural.contract import ShadingPoint, coverage_of  # noqa: E402
from mtlx2neural.mitsuba import load_mitsuba  # noqa: E402
from mtlx2neural.mitsuba.render import bind, in_scene_flip  # noqa: E402
from mtlx2neural.mitsuba.scene import render, scene_dict  # noqa: E402
from mtlx2neural.pipeline.convert import convert_asset  # noqa: E402
from mtlx2neural.pipeline.options import ConvertOptions  # noqa: E402
from mtlx2neural.report.scene_view import gather, scene_mesh  # noqa: E402
from mtlx2neural.train.config import preset  # noqa: E402

FURNACE_ANGLES = (0.0, 45.0, 75.0)
FURNACE_TEXELS = 16
FURNACE_SAMPLES = 4096


def convert(asset: Path, folder: Path, decoder: str, iterations: int | None) -> Path:
    """The neural layer of ``asset`` converted with ``fast`` (``decoder``; ``iterations`` steps when given) in
    a copy of its folder under ``folder``."""
    copy = folder / f"{asset.stem}_{decoder}"
    shutil.copytree(asset.parent, copy, dirs_exist_ok=True)
    train = preset("fast", decoder=decoder, **({"iterations": iterations} if iterations else {}))
    convert_asset(copy / asset.name, ConvertOptions(train=train, progress=False, device="cpu", workers=1,
                                                    flagged="neural"))
    return copy / f"{asset.stem}_neural.usda"


def timed_render(mi, layer: Path, model: str, res: int, spp: int, seed: int = 0) -> tuple[float, float]:
    """(seconds of the second of two identical renders, the image's mean) of ``layer``'s whole stage."""
    source, entries = gather(layer)
    scene = scene_mesh(source, entries, res, seed)
    bindings = [bind(mi, e, model, layer, source, [])[0] for e in entries]
    loaded = mi.load_dict(scene_dict(mi, scene, bindings, res, spp, max_depth=3))
    render(mi, loaded, seed=seed)  # compiles the kernels
    t = time.perf_counter()
    img = render(mi, loaded, seed=seed)
    return time.perf_counter() - t, float(img.mean())


def covered_uvs(reference) -> np.ndarray:
    """:data:`FURNACE_TEXELS` seeded uniform uvs where ``reference`` is there (coverage at least 0.5: a
    cut-out's holes show what lies behind, not the BSDF)."""
    uv = np.random.default_rng(1).random((64 * FURNACE_TEXELS, 2)).astype(np.float32)
    cover = coverage_of(reference, ShadingPoint(uv=torch.from_numpy(uv)))
    keep = uv if cover is None else uv[cover.numpy() >= 0.5]
    return keep[:FURNACE_TEXELS]


def furnace(mi, spec: dict, uvs: np.ndarray) -> float:
    """Mean over ``uvs`` and :data:`FURNACE_ANGLES` of the directional albedo (mean RGB sample weight) that
    the BSDF ``spec``'s own ``sample`` gives in Mitsuba."""
    import drjit as dr  # Local: Dr.Jit comes with Mitsuba, an optional dependency.

    bsdf = mi.load_dict(spec)
    rng = np.random.default_rng(0)
    values = []
    for deg in FURNACE_ANGLES:
        th = math.radians(deg)
        n = FURNACE_SAMPLES * len(uvs)
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.wi = mi.Vector3f(math.sin(th), 0.0, math.cos(th))
        si.uv = mi.Point2f(np.repeat(uvs[:, 0], FURNACE_SAMPLES).astype(np.float32),
                           np.repeat(uvs[:, 1], FURNACE_SAMPLES).astype(np.float32))
        u = rng.random((3, n)).astype(np.float32)
        with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, False), dr.scoped_set_flag(dr.JitFlag.SymbolicCalls, False):
            _, weight = bsdf.sample(mi.BSDFContext(), si, mi.Float(u[0]), mi.Point2f(u[1], u[2]))
        values.append(float(np.asarray(weight, dtype=np.float64).mean()))
    return float(np.mean(values))


def timing(mi, asset: Path, decoders: list[str], iterations: int, res: int, spp: int) -> None:
    """Print table 1 (module docstring)."""
    samples = res * res * spp
    with tempfile.TemporaryDirectory() as tmp:
        layers = {d: convert(asset, Path(tmp), d, iterations) for d in decoders}
        ref_s, ref_mean = timed_render(mi, layers[decoders[0]], "reference", res, spp)
        print(f"## Time per sample: {asset.name}, whole stage, {res}², {spp} spp, max_depth 3\n")
        print("| BSDFs | seconds | µs / sample | neural / reference | image mean |")
        print("|---|---|---|---|---|")
        print(f"| mtlx_reference | {ref_s:.2f} | {1e6 * ref_s / samples:.2f} | 1 | {ref_mean:.4f} |")
        for d, layer in layers.items():
            s, mean = timed_render(mi, layer, "neural", res, spp)
            print(f"| mtlx_neural {d} | {s:.2f} | {1e6 * s / samples:.2f} | {s / ref_s:.3f} | {mean:.4f} |")
    print()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--asset", default=str(ROOT / "samples" / "scene" / "glow_and_leaves.usda"))
    ap.add_argument("--layer", help="a fast conversion of --asset (default: <asset stem>_neural.usda beside it, "
                    "converted first when missing)")
    ap.add_argument("--decoders", default="2x16,2x32,3x64")
    ap.add_argument("--iterations", type=int, default=200, help="training steps of the timing models")
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--skip-timing", action="store_true", help="only the fidelity table")
    args = ap.parse_args()
    mi = load_mitsuba()
    asset = Path(args.asset).resolve()

    if not args.skip_timing:
        timing(mi, asset, args.decoders.split(","), args.iterations, args.res, args.spp)
    layer = Path(args.layer) if args.layer else asset.with_name(f"{asset.stem}_neural.usda")
    if not layer.is_file():
        convert_asset(asset, ConvertOptions(train=preset("fast"), progress=False, device="cpu", workers=1))
    source, entries = gather(layer)
    flips = in_scene_flip(layer)
    print(f"## Fidelity in Mitsuba: {layer.name}\n")
    print("| material | in-scene HDR FLIP, Mitsuba | torch renderer (record) | furnace: neural / reference albedo |")
    print("|---|---|---|---|")
    for e in entries:
        if e.status not in ("converted", "flagged"):
            continue
        uvs = covered_uvs(e.models["reference"])
        ref = furnace(mi, {"type": "mtlx_reference", "filename": str(source), "material": e.prim}, uvs)
        neu = furnace(mi, {"type": "mtlx_neural", "filename": str(layer), "material": e.prim}, uvs)
        row = flips.get(e.prim, {})
        print(f"| {e.prim.rsplit('/', 1)[-1]} | {row.get('mitsuba', math.nan):.4f} | {row.get('record') or math.nan:.4f}"
              f" | {neu / ref if ref > 0 else math.nan:.3f} ({neu:.4f} / {ref:.4f}) |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
