"""A near-delta coat's highlight under a key light, against the mollification floor that training keeps.

Run:  python benchmarks/bench_coat_peak.py [ASSET.mtlx] [--floors 1,0.5,0.25,0] [--res 256] [--spp 64] [--out DIR]

Converts ASSET (default: MaterialX's ``standard_surface_carpaint``, a coat of roughness 0 over an
anisotropic base) once per floor with the project's command (``--preset fast --mollify-min-degrees F``),
loads the exported layer (:func:`mtlx2neural.load_neural`, what a consumer reads) and renders the unit
sphere under the first summary view's directional light (its mirror highlight on the visible surface),
``res``² pixels at ``spp`` jittered samples, for the reference and the model. Prints one Markdown row per
floor: the training seconds, the peak pixel (max luminance) of each render and their ratio, the
summary's ``flip_mean`` (three directional views and the sky), its sky view, and the energy check's
lowest per-level ratio. The reference's peak is its pixel integral at this resolution: a narrower lobe
than a pixel's footprint is averaged over the pixel, so the peak grows with ``res`` for a delta coat.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

import mtlx2neural as m2n
from mtlx2neural.render.renderer import VIEWS, render

DEFAULT = (Path(__file__).resolve().parents[2] / "shared" / "assets" / "materialx" / "resources" / "Materials"
           / "Examples" / "StandardSurface" / "standard_surface_carpaint.mtlx")
LUMA = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)


def peak(image: np.ndarray) -> float:
    """The brightest pixel's luminance (linear)."""
    return float((image @ LUMA).max())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("asset", type=Path, nargs="?", default=DEFAULT)
    ap.add_argument("--floors", default="1,0.5,0.25,0", help="mollification floors in degrees, comma-separated")
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--out", type=Path, default=None, help="folder for the conversions (default: a temporary one)")
    args = ap.parse_args()
    base = args.out or Path(tempfile.mkdtemp(prefix="bench_coat_peak_"))
    view = VIEWS[0]
    print(f"{args.asset.name}, --preset fast, view azimuth {view.azimuth:g} elevation {view.elevation:g}, "
          f"{args.res}^2, {args.spp} spp")
    print("| floor (deg) | train s | peak reference | peak neural | neural / reference | flip_mean | sky view | "
          "min energy |")
    print("|---|---|---|---|---|---|---|---|")
    ref_peak = None
    for floor in (float(f) for f in args.floors.split(",")):
        out = base / f"floor_{floor:g}".replace(".", "p")
        cmd = [sys.executable, "-m", "mtlx2neural.cli", str(args.asset), "-o", str(out), "--preset", "fast",
               "--force", "--quiet", "--flagged", "neural", "--mollify-min-degrees", str(floor)]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
        (record,) = [json.loads(p.read_text()) for p in out.glob("*/summary.json")]
        model = m2n.load_neural(out.parent / f"{out.name}.usda", record["material"])
        texels = tuple(record["resolution"])
        if ref_peak is None:
            reference = m2n.load_reference(args.asset, record["mtlx_material"])
            ref_peak = peak(render(reference, view, args.res, args.spp, texels, seed=0))
        p = peak(render(model, view, args.res, args.spp, texels, seed=0))
        energy = (record.get("energy") or {}).get("min_ratio", float("nan"))
        print(f"| {floor:g} | {record['train_seconds']:.0f} | {ref_peak:.3g} | {p:.3g} | {p / ref_peak:.3f} | "
              f"{record['flip_mean']:.4f} | {record['flip_per_view'][-1]:.4f} | {energy:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
