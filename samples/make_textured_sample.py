"""Write ``samples/textured/ceramic_and_metal.usda`` and its procedural textures.

Run:  python samples/make_textured_sample.py [OUT_DIR] [--res 1024]

Two MaterialX UsdShade materials on two meshes, with textures generated here
(no third-party files):
- /World/Looks/GlazedCeramic: a standard_surface with a clear coat over a
  tiled, colour-varying base (sRGB albedo texture) with a tile-relief normal map;
- /World/Looks/BrushedMetal: an anisotropic metal whose roughness and normal
  maps carry brushing streaks.
Files are written to a temporary name and renamed (never half-written).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade


def _save(path: Path, img: np.ndarray) -> None:
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    out = oiio.ImageOutput.create(str(tmp))
    out.open(str(tmp), oiio.ImageSpec(img.shape[1], img.shape[0], img.shape[2], "uint8"))
    out.write_image((np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8))
    out.close()
    os.replace(tmp, path)


def _normals_from_height(h: np.ndarray, strength: float) -> np.ndarray:
    gy, gx = np.gradient(h)
    n = np.stack([-gx * strength, gy * strength, np.ones_like(h)], -1)  # image rows run downwards
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return n * 0.5 + 0.5


def make_textures(folder: Path, res: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    y, x = np.meshgrid(np.linspace(0, 1, res, endpoint=False), np.linspace(0, 1, res, endpoint=False), indexing="ij")
    tiles = 8
    tx, ty = (x * tiles) % 1.0, (y * tiles) % 1.0
    grout = np.minimum(np.minimum(tx, 1 - tx), np.minimum(ty, 1 - ty))
    relief = np.clip(grout / 0.06, 0, 1) ** 0.5  # 0 in the grout, 1 on the tile
    tile_id = (np.floor(x * tiles) * 13 + np.floor(y * tiles) * 7) % 5
    palette = np.array([[0.75, 0.82, 0.88], [0.62, 0.74, 0.84], [0.80, 0.77, 0.66], [0.55, 0.66, 0.72],
                        [0.86, 0.86, 0.82]])
    albedo = palette[tile_id.astype(int)] * (0.85 + 0.15 * relief[..., None]) \
        + rng.normal(0, 0.015, (res, res, 1))
    albedo = np.where(relief[..., None] < 0.2, np.array([0.35, 0.33, 0.3]), albedo)
    streaks = rng.normal(0, 1, (res, 1)).repeat(res, 1)  # constant along x: brushing direction
    streaks = np.convolve(streaks[:, 0], np.ones(5) / 5, mode="same")[:, None].repeat(res, 1)
    files = {
        "ceramic_albedo": (albedo, "ceramic_albedo.png"),
        "ceramic_normal": (_normals_from_height(relief, res / 64.0), "ceramic_normal.png"),
        "metal_roughness": ((0.3 + 0.08 * streaks)[..., None], "metal_roughness.png"),
        "metal_normal": (_normals_from_height(streaks * 0.02, res / 16.0), "metal_normal.png"),
    }
    return save_textures(folder, files)


def save_textures(folder: Path, files: dict) -> dict:
    """Write ``{key: (image [H, W, C] in [0, 1], file name)}`` into ``folder`` as 8-bit PNGs; {key: file name}."""
    out = {}
    for key, (img, name) in files.items():
        _save(folder / name, img.astype(np.float32))
        out[key] = name
    return out


def _image(stage, mat_path, name, file, mx_type, colorspace=None):
    sh = UsdShade.Shader.Define(stage, f"{mat_path}/{name}")
    sh.CreateIdAttr(f"ND_image_{mx_type}")
    inp = sh.CreateInput("file", Sdf.ValueTypeNames.Asset)
    inp.Set(Sdf.AssetPath(f"./{file}"))
    if colorspace:
        inp.GetAttr().SetColorSpace(colorspace)
    return sh.CreateOutput("out", Sdf.ValueTypeNames.Float3 if mx_type != "float" else Sdf.ValueTypeNames.Float)


def _normal_map(stage, mat_path, file):
    img = _image(stage, mat_path, "normal_tex", file, "vector3")
    nm = UsdShade.Shader.Define(stage, f"{mat_path}/normal_map")
    nm.CreateIdAttr("ND_normalmap_float")
    nm.CreateInput("in", Sdf.ValueTypeNames.Float3).ConnectToSource(img)
    return nm.CreateOutput("out", Sdf.ValueTypeNames.Float3)


def _surface(stage, mat_path):
    mat = UsdShade.Material.Define(stage, mat_path)
    sh = UsdShade.Shader.Define(stage, f"{mat_path}/surface")
    sh.CreateIdAttr("ND_standard_surface_surfaceshader")
    mat.CreateSurfaceOutput("mtlx").ConnectToSource(sh.CreateOutput("out", Sdf.ValueTypeNames.Token))
    return mat, sh


def quad(stage, path: str, material, offset: float = 0.0):
    """A 2x2 quad in the y = 0 plane centred at x = ``offset``, uv over [0, 1]^2, bound to ``material``."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr([(offset - 1, 0, -1), (offset + 1, 0, -1), (offset + 1, 0, 1), (offset - 1, 0, 1)])
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 3, 2, 1])
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set([(0, 0), (0, 1), (1, 1), (1, 0)])
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    return mesh


def build(folder: Path, res: int = 1024) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    files = make_textures(folder, res)
    path = folder / "ceramic_and_metal.usda"
    tmp = folder / "ceramic_and_metal.tmp.usda"
    stage = Usd.Stage.CreateNew(str(tmp))
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    f, c3, v3 = Sdf.ValueTypeNames.Float, Sdf.ValueTypeNames.Color3f, Sdf.ValueTypeNames.Float3

    ceramic, sh = _surface(stage, "/World/Looks/GlazedCeramic")
    sh.CreateInput("base_color", c3).ConnectToSource(
        _image(stage, "/World/Looks/GlazedCeramic", "albedo_tex", files["ceramic_albedo"], "color3", "srgb_texture"))
    sh.CreateInput("normal", v3).ConnectToSource(_normal_map(stage, "/World/Looks/GlazedCeramic", files["ceramic_normal"]))
    sh.CreateInput("specular_roughness", f).Set(0.45)
    sh.CreateInput("coat", f).Set(1.0)
    sh.CreateInput("coat_roughness", f).Set(0.05)

    metal, sh = _surface(stage, "/World/Looks/BrushedMetal")
    sh.CreateInput("base_color", c3).Set(Gf.Vec3f(0.91, 0.92, 0.92))
    sh.CreateInput("metalness", f).Set(1.0)
    sh.CreateInput("specular_anisotropy", f).Set(0.7)
    sh.CreateInput("specular_roughness", f).ConnectToSource(
        _image(stage, "/World/Looks/BrushedMetal", "roughness_tex", files["metal_roughness"], "float"))
    sh.CreateInput("normal", v3).ConnectToSource(_normal_map(stage, "/World/Looks/BrushedMetal", files["metal_normal"]))

    for name, mat, offset in (("Vase", ceramic, -1.5), ("Plate", metal, 1.5)):
        quad(stage, f"/World/Geo/{name}", mat, offset)
    stage.GetRootLayer().Save()
    os.replace(tmp, path)
    return path


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("out", nargs="?", default=str(Path(__file__).resolve().parent / "textured"))
    ap.add_argument("--res", type=int, default=1024)
    a = ap.parse_args()
    print(f"wrote {build(Path(a.out), a.res)}")
