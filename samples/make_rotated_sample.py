"""Write ``samples/rotated/spun_metal.usda`` and its rotation texture.

Run:  python samples/make_rotated_sample.py [OUT_DIR] [--res 16]

One MaterialX UsdShade material on a quad, with a texture generated here (no
third-party files):
- /World/Looks/SpunMetal: a standard_surface metal (specular_anisotropy 0.8,
  specular_roughness 0.5) brushed in circles about the quad's centre: its
  ``specular_rotation`` (0-1 = 0-360 degrees; MaterialX's ``rotate3d`` turns the
  tangent *clockwise* about the normal, from +u) is read from a small texture, so
  the lobe's tangent is along the circles: along u at the top and bottom edges'
  midpoints, along v at the left and right ones.

The rotation is stored over a full turn (not modulo half a turn): where it wraps
from 1 back to 0, bilinear filtering gives 0.5 = 180 degrees, the same lobe as 0.
Files are written to a temporary name and renamed (never half-written).
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

MATERIAL = "/World/Looks/SpunMetal"


def rotation_map(res: int) -> np.ndarray:
    """[res, res] specular_rotation (fraction of a turn, clockwise) at the texel centres, row 0 at the top
    (v = 1): the tangent of the circle about uv (0.5, 0.5) through each texel."""
    centre = (np.arange(res) + 0.5) / res
    v, u = np.meshgrid(centre[::-1], centre, indexing="ij")
    angle = np.arctan2(v - 0.5, u - 0.5) + 0.5 * math.pi  # perpendicular to the radius
    return np.mod(-angle / (2.0 * math.pi), 1.0)  # clockwise: minus the counter-clockwise angle


def _save(path: Path, img: np.ndarray) -> None:
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    out = oiio.ImageOutput.create(str(tmp))
    out.open(str(tmp), oiio.ImageSpec(img.shape[1], img.shape[0], 1, "uint16"))
    out.write_image((np.clip(img, 0, 1)[..., None] * 65535 + 0.5).astype(np.uint16))  # [H, W, 1]: rows, columns
    out.close()
    os.replace(tmp, path)


def build(folder: Path, res: int = 16) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    _save(folder / "spun_rotation.png", rotation_map(res))
    path = folder / "spun_metal.usda"
    tmp = folder / "spun_metal.tmp.usda"
    stage = Usd.Stage.CreateNew(str(tmp))
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    f, c3 = Sdf.ValueTypeNames.Float, Sdf.ValueTypeNames.Color3f

    mat = UsdShade.Material.Define(stage, MATERIAL)
    sh = UsdShade.Shader.Define(stage, f"{MATERIAL}/surface")
    sh.CreateIdAttr("ND_standard_surface_surfaceshader")
    mat.CreateSurfaceOutput("mtlx").ConnectToSource(sh.CreateOutput("out", Sdf.ValueTypeNames.Token))
    sh.CreateInput("base_color", c3).Set(Gf.Vec3f(0.95, 0.93, 0.88))
    sh.CreateInput("metalness", f).Set(1.0)
    sh.CreateInput("specular_roughness", f).Set(0.5)
    sh.CreateInput("specular_anisotropy", f).Set(0.8)
    tex = UsdShade.Shader.Define(stage, f"{MATERIAL}/rotation_tex")
    tex.CreateIdAttr("ND_image_float")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath("./spun_rotation.png"))
    sh.CreateInput("specular_rotation", f).ConnectToSource(tex.CreateOutput("out", f))

    mesh = UsdGeom.Mesh.Define(stage, "/World/Geo/Disc")
    mesh.CreatePointsAttr([(-1, 0, -1), (1, 0, -1), (1, 0, 1), (-1, 0, 1)])
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 3, 2, 1])
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set([(0, 0), (0, 1), (1, 1), (1, 0)])
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    stage.GetRootLayer().Save()
    os.replace(tmp, path)
    return path


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("out", nargs="?", default=str(Path(__file__).resolve().parent / "rotated"))
    ap.add_argument("--res", type=int, default=16)
    a = ap.parse_args()
    print(f"wrote {build(Path(a.out), a.res)}")
