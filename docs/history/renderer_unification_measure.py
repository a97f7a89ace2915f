"""Measure what unifying the renderer changed (docs/history/renderer-unification-2026-12-02.md).

Runs on any version whose ``render``/``compare`` keep their public API, so the same script
measured the old orthographic code path and the new one (``render_scene`` with an
``OrthographicCamera``). A textured standard_surface (a seeded 256x256 random checker as base
colour) is the reference; a small analytic fit (64x64 texels, 150 Adam steps, seed 0) stands in
for a trained model. Prints, per view, compare()'s HDR FLIP between the two, the reference's own
noise (FLIP between two seeds) and the level of detail at a few pixels.

    .venv/bin/python docs/history/renderer_unification_measure.py
"""

from __future__ import annotations

import math
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))

from materials import TEXTURED_MTLX  # noqa: E402

import mtlx2neural as m2n  # noqa: E402
from mtlx2neural.baseline.analytic_model import fit_analytic  # noqa: E402
from mtlx2neural.contract import as_point  # noqa: E402
from mtlx2neural.render.renderer import VIEWS, View, compare, image_errors, render  # noqa: E402
from mtlx2neural.textures.parameter_stack import build_parameter_stack  # noqa: E402


class LodEcho:
    """Renders the level of detail it is asked for, as grey (f*cos = lod)."""

    def eval(self, wi, wo, at=None):
        return as_point(at).lod[:, None].expand(-1, 3).clone()


def write_checker(path: Path) -> None:
    import OpenImageIO as oiio

    g = np.random.default_rng(0)
    cells = g.uniform(0.05, 0.95, (16, 16, 3)).astype(np.float32)
    img = np.kron(cells, np.ones((16, 16, 1), np.float32))
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(256, 256, 3, "uint8"))
    out.write_image((img * 255 + 0.5).astype(np.uint8))
    out.close()


def main() -> None:
    torch.manual_seed(0)
    folder = Path(tempfile.mkdtemp())
    (folder / "tex.mtlx").write_text(TEXTURED_MTLX)
    write_checker(folder / "albedo.png")
    ref = m2n.load_reference(folder / "tex.mtlx", "Tex")
    stack = build_parameter_stack(ref.compiled, resolution=(64, 64))
    fit = fit_analytic(ref, stack, iterations=150, batch=2048, seed=0)
    print("compare(ref, analytic fit, texels=(64, 64), res=96, spp=32): HDR FLIP per view")
    for e in compare(ref, fit, (64, 64), label="analytic"):
        v = e["view"]
        print(f"  view az={v.azimuth:5.0f} el={v.elevation:4.0f}: flip={e['flip']:.4f} mae={e['mae']:.5f}")
    print("reference noise: FLIP(render seed 0, render seed 1), res=96")
    for spp in (4, 32):
        row = [image_errors(render(ref, v, 96, spp, seed=0), render(ref, v, 96, spp, seed=1))["flip"] for v in VIEWS]
        print(f"  spp={spp:2d}: " + "  ".join(f"{f:.4f}" for f in row))
    # The light at the camera so that every visible pixel is lit (a renderer may skip unlit ones).
    el = math.radians(15.0)
    view = View(0.0, 15.0, (0.0, math.sin(el), math.cos(el)), 1.0)
    lod = render(LodEcho(), view, res=96, spp=1, texels=(256, 256), footprint=1.0)[..., 0]
    print("level of detail (texels 256x256, res 96, whole-pixel footprint), view az=0 el=15, row 48:")
    cols = (48, 60, 72, 80, 86, 90, 92)
    print("  column: " + " ".join(f"{c:6d}" for c in cols))
    print("  lod:    " + " ".join(f"{lod[48, c]:6.2f}" for c in cols))
    rows = (48, 36, 24, 16, 10, 6)
    print("  column 48, rows " + " ".join(f"{r:6d}" for r in rows))
    print("  lod:            " + " ".join(f"{lod[r, 48]:6.2f}" for r in rows))


if __name__ == "__main__":
    main()
