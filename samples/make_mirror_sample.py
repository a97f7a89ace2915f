"""Write ``samples/mirror/polished_metal.usda`` and its procedural textures: a near-mirror textured metal.

Run:  python samples/make_mirror_sample.py [OUT_DIR] [--res 256]

One MaterialX UsdShade material on a quad, with textures generated here (no third-party files):
/World/Looks/PolishedMetal, a standard_surface with metalness 1, a gold base colour, a roughness
texture of smooth blotches between 0.02 and 0.3 (mostly polished, some worn patches) and a normal
map of shallow hammer dents. Most of its directional albedo sits in lobes a few degrees wide: the
case where a loss that follows the median of noisy targets trains the material to black. Files are
written to a temporary name and renamed (never half-written).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom

_spec = importlib.util.spec_from_file_location("make_textured_sample",
                                               Path(__file__).resolve().parent / "make_textured_sample.py")
_textured = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_textured)

ROUGHNESS_RANGE = (0.02, 0.3)


def _smooth_noise(rng, res: int, cells: int) -> np.ndarray:
    """Periodic value noise in [0, 1]: a ``cells`` x ``cells`` random grid, bicubically smoothed."""
    grid = rng.uniform(0, 1, (cells, cells))
    t = np.arange(res) / res * cells
    i0 = np.floor(t).astype(int)
    f = t - i0
    f = f * f * (3 - 2 * f)
    a = grid[i0 % cells][:, i0 % cells]
    b = grid[i0 % cells][:, (i0 + 1) % cells]
    c = grid[(i0 + 1) % cells][:, i0 % cells]
    d = grid[(i0 + 1) % cells][:, (i0 + 1) % cells]
    fx, fy = f[None, :], f[:, None]
    return (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy


def make_textures(folder: Path, res: int, seed: int = 3) -> dict:
    rng = np.random.default_rng(seed)
    wear = _smooth_noise(rng, res, 6) ** 3  # mostly near 0: polished, a few worn patches
    lo, hi = ROUGHNESS_RANGE
    roughness = lo + (hi - lo) * wear / max(float(wear.max()), 1e-6)
    dents = sum(_smooth_noise(rng, res, c) / c for c in (12, 24))  # shallow hammer dents
    files = {"roughness": (roughness[..., None], "polished_roughness.png"),
             "normal": (_textured._normals_from_height(dents, res / 48.0), "polished_normal.png")}
    return _textured.save_textures(folder, files)


def build(folder: Path, res: int = 256) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    files = make_textures(folder, res)
    path = folder / "polished_metal.usda"
    tmp = folder / "polished_metal.tmp.usda"
    stage = Usd.Stage.CreateNew(str(tmp))
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    f, c3, v3 = Sdf.ValueTypeNames.Float, Sdf.ValueTypeNames.Color3f, Sdf.ValueTypeNames.Float3
    looks = "/World/Looks/PolishedMetal"
    mat, sh = _textured._surface(stage, looks)
    sh.CreateInput("base_color", c3).Set(Gf.Vec3f(1.0, 0.78, 0.34))
    sh.CreateInput("metalness", f).Set(1.0)
    sh.CreateInput("specular_roughness", f).ConnectToSource(
        _textured._image(stage, looks, "roughness_tex", files["roughness"], "float"))
    sh.CreateInput("normal", v3).ConnectToSource(_textured._normal_map(stage, looks, files["normal"]))
    _textured.quad(stage, "/World/Geo/Tray", mat)
    stage.GetRootLayer().Save()
    os.replace(tmp, path)
    return path


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("out", nargs="?", default=str(Path(__file__).resolve().parent / "mirror"))
    ap.add_argument("--res", type=int, default=256)
    a = ap.parse_args()
    print(f"wrote {build(Path(a.out), a.res)}")
