"""Reference BRDF throughput (evals/s, batch 2^18) and load_reference time.

Run:  python benchmarks/bench_reference.py [--batch 262144] [--repeats 5] [--compiled]

(``sample`` includes the full mixture pdf and an ``eval`` of the sampled direction.)

Materials: standard_surface default, a layered TestSuite material and
open_pbr_surface default. Prints a Markdown table for BENCHMARKS.md with the
machine it ran on. Ratios between rows of one run are meaningful; absolute
numbers move with machine load.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import MaterialX as mx
import torch

import mtlx2neural as m2n

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "assets" / "materialx" / "resources" / "Materials"


def _open_pbr_default(tmp: Path) -> Path:
    doc = mx.createDocument()
    sh = doc.addNode("open_pbr_surface", "sh", "surfaceshader")
    doc.addMaterialNode("OpenPBR_Default", sh)
    path = tmp / "open_pbr_default.mtlx"
    mx.writeToXmlFile(doc, str(path))
    return path


def _directions(n: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    v = torch.randn(2, n, 3, generator=g)
    v = v / v.norm(dim=-1, keepdim=True)
    v[..., 2] = v[..., 2].abs()
    return v[0].contiguous(), v[1].contiguous()


def bench(path: Path, material: str | None, batch: int, repeats: int, compiled: bool):
    t0 = time.perf_counter()
    m = m2n.load_reference(path, material)
    load_s = time.perf_counter() - t0
    wi, wo = _directions(batch)
    fn = torch.compile(m.eval) if compiled else m.eval
    with torch.no_grad():
        fn(wi, wo)  # warm-up (and compilation)
        best = float("inf")
        for _ in range(repeats):
            t = time.perf_counter()
            fn(wi, wo)
            best = min(best, time.perf_counter() - t)
        u = torch.rand(batch, 2, generator=torch.Generator().manual_seed(1))
        m.sample(wi, u)
        best_s = float("inf")
        for _ in range(repeats):
            t = time.perf_counter()
            m.sample(wi, u)
            best_s = min(best_s, time.perf_counter() - t)
    return load_s, batch / best, [k["closure"] for k in m.describe()["lobes_kept"]], batch / best_s


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, default=1 << 18)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--compiled", action="store_true", help="also time torch.compile'd eval")
    args = ap.parse_args()
    import tempfile

    tmp = Path(tempfile.mkdtemp())
    cases = [
        ("standard_surface default", SHARED / "Examples/StandardSurface/standard_surface_default.mtlx", None),
        ("layered: TestSuite layer_bsdf_test1 (4 lobes, 3 layers)", SHARED / "TestSuite/pbrlib/bsdf/layer_bsdf.mtlx",
         "layer_bsdf_test1_out"),
        ("open_pbr_surface default", _open_pbr_default(tmp), None),
        ("carpaint sample (coat, metal, specular, diffuse)", Path(__file__).resolve().parents[1] / "samples/layered_spheres.usda",
         "/World/Looks/CarPaint"),
    ]
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"torch {torch.__version__}, {torch.get_num_threads()} threads, batch {args.batch}")
    print("| material | lobes | load_reference (s) | eager eval/s | eager sample/s |"
          + (" torch.compile eval/s |" if args.compiled else ""))
    print("|---|---|---|---|---|" + ("---|" if args.compiled else ""))
    for label, path, mat in cases:
        if not path.exists():
            print(f"| {label} | skipped: {path} missing | | |")
            continue
        load_s, eps, lobes, sps = bench(path, mat, args.batch, args.repeats, False)
        row = f"| {label} | {', '.join(lobes)} | {load_s:.3f} | {eps / 1e6:.2f} M | {sps / 1e6:.2f} M |"
        if args.compiled:
            row += f" {bench(path, mat, args.batch, args.repeats, True)[1] / 1e6:.2f} M |"
        print(row)


if __name__ == "__main__":
    main()
