"""Write ``samples/udim/udim_tiles.usda`` and its UDIM texture set ``base.<UDIM>.png``.

Run:  python samples/make_udim_sample.py [OUT_DIR] [--res 16]

One MaterialX UsdShade material on an L-shaped mesh whose UVs span three UDIM tiles, with textures
generated here (no third-party files):
- /World/Looks/UdimTiles: a ``standard_surface`` (specular 0.3, roughness 0.6) whose ``base_color``
  reads ``./base.<UDIM>.png`` (``ND_image_color3``), one ``res`` x ``res`` 8-bit PNG per tile, each
  tile a different colour and pattern: 1001 a red checkerboard, 1002 green stripes along v, 1011
  a blue ring;
- tile 1012 (yellow) is also on disk, but no face reaches it: a conversion trains 1001, 1002 and
  1011 only (the tiles the mesh's UVs overlap), so it shows which tiles the meshes pick;
- /World/Geo/Tiles: three unit quads in the y = 0 plane (normal +y), quad (tu, tv) at x in
  [tu, tu + 1], z in [-(tv + 1), -tv], with faceVarying ``st`` = (x, -z): uv in tiles 1001
  (0, 0), 1002 (1, 0) and 1011 (0, 1);
- /World/Sun: a DistantLight from above (rotateXYZ (-60, 30, 0)), so the in-scene measure has a
  light; no camera (the measure frames the mesh itself).

Files are written to a temporary name and renamed (never half-written).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade

MATERIAL = "/World/Looks/UdimTiles"
MESH = "/World/Geo/Tiles"
TRAINED = (1001, 1002, 1011)
"""Tiles the mesh's UVs overlap (a conversion trains these)."""
UNTOUCHED = 1012
"""A tile on disk that no face reaches."""


def tile_image(udim: int, res: int) -> np.ndarray:
    """[res, res, 3] sRGB values in [0, 1] of tile ``udim`` (row 0 at the top, v = 1 of the tile)."""
    i = np.arange(res)
    rows, cols = np.meshgrid(i, i, indexing="ij")
    img = np.zeros((res, res, 3))
    if udim == 1001:  # red checkerboard, 4-texel squares
        light = ((rows // 4 + cols // 4) % 2 == 0)[..., None]
        img[:] = np.where(light, (0.85, 0.15, 0.12), (0.55, 0.06, 0.05))
    elif udim == 1002:  # green stripes along v (columns alternate every 2 texels)
        light = ((cols // 2) % 2 == 0)[..., None]
        img[:] = np.where(light, (0.2, 0.8, 0.25), (0.08, 0.45, 0.1))
    elif udim == 1011:  # blue ring about the tile's centre
        r = np.hypot(rows + 0.5 - res / 2, cols + 0.5 - res / 2) / (res / 2)
        ring = ((r > 0.35) & (r < 0.7))[..., None]
        img[:] = np.where(ring, (0.15, 0.3, 0.9), (0.06, 0.12, 0.5))
    else:  # yellow (the untouched tile)
        img[:] = (0.9, 0.8, 0.1)
    return img


def _save(path: Path, img: np.ndarray) -> None:
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    out = oiio.ImageOutput.create(str(tmp))
    out.open(str(tmp), oiio.ImageSpec(img.shape[1], img.shape[0], 3, "uint8"))
    out.write_image((np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8))
    out.close()
    os.replace(tmp, path)


def build(folder: Path, res: int = 16) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for udim in (*TRAINED, UNTOUCHED):
        _save(folder / f"base.{udim}.png", tile_image(udim, res))
    path = folder / "udim_tiles.usda"
    tmp = folder / "udim_tiles.tmp.usda"
    stage = Usd.Stage.CreateNew(str(tmp))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    f, c3 = Sdf.ValueTypeNames.Float, Sdf.ValueTypeNames.Color3f

    mat = UsdShade.Material.Define(stage, MATERIAL)
    sh = UsdShade.Shader.Define(stage, f"{MATERIAL}/surface")
    sh.CreateIdAttr("ND_standard_surface_surfaceshader")
    mat.CreateSurfaceOutput("mtlx").ConnectToSource(sh.CreateOutput("out", Sdf.ValueTypeNames.Token))
    sh.CreateInput("base", f).Set(1.0)
    sh.CreateInput("specular", f).Set(0.3)
    sh.CreateInput("specular_roughness", f).Set(0.6)
    tex = UsdShade.Shader.Define(stage, f"{MATERIAL}/base_tex")
    tex.CreateIdAttr("ND_image_color3")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath("./base.<UDIM>.png"))
    sh.CreateInput("base_color", c3).ConnectToSource(tex.CreateOutput("out", c3))

    mesh = UsdGeom.Mesh.Define(stage, MESH)
    points, indices, st = [], [], []
    for udim in TRAINED:
        tu, tv = (udim - 1001) % 10, (udim - 1001) // 10
        corners = [(tu, tv), (tu + 1, tv), (tu + 1, tv + 1), (tu, tv + 1)]  # counter-clockwise seen from +y
        for u, v in corners:
            indices.append(len(points))
            points.append(Gf.Vec3f(u, 0.0, -v))
            st.append(Gf.Vec2f(u, v))
    mesh.CreatePointsAttr(points)
    mesh.CreateFaceVertexCountsAttr([4] * len(TRAINED))
    mesh.CreateFaceVertexIndicesAttr(indices)
    mesh.CreateNormalsAttr([Gf.Vec3f(0, 1, 0)] * len(points))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                      UsdGeom.Tokens.faceVarying)
    primvar.Set(st)
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)

    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(3.0)
    UsdGeom.XformCommonAPI(sun.GetPrim()).SetRotate(Gf.Vec3f(-60.0, 30.0, 0.0))
    stage.GetRootLayer().Save()
    os.replace(tmp, path)
    return path


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("out", nargs="?", default=str(Path(__file__).resolve().parent / "udim"))
    ap.add_argument("--res", type=int, default=16)
    a = ap.parse_args()
    print(f"wrote {build(Path(a.out), a.res)}")
