"""Write ``samples/scene/glow_and_leaves.usda`` and its procedural textures: a small game-style scene.

Run:  python samples/make_scene_sample.py [OUT_DIR] [--res 128]

Three UsdPreviewSurface materials (the USD-native shading model game assets use), each on its own
quad, with a camera and a distant light; textures are generated here (no third-party files):

- /World/Looks/Lava: dark rock (``diffuseColor`` texture, roughness 0.8) whose cracks glow
  (``emissiveColor`` texture, up to 4 in linear RGB): the emissive case.
- /World/Looks/Leaf: a green leaf whose silhouette is the alpha of its RGBA texture, read by
  ``opacity`` with ``opacityThreshold`` 0.5: the cut-out case (half of the quad is empty).
- /World/Looks/Gold: metallic 1, a gold colour and a roughness texture between 0.03 and 0.25: the
  near-mirror case.

Files are written to a temporary name and renamed (never half-written).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade

_here = Path(__file__).resolve().parent


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, _here / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


_textured = _load("make_textured_sample")
_mirror = _load("make_mirror_sample")


def _save_exr(path: Path, img: np.ndarray) -> str:
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    out = oiio.ImageOutput.create(str(tmp))
    out.open(str(tmp), oiio.ImageSpec(img.shape[1], img.shape[0], img.shape[2], "half"))
    out.write_image(img.astype(np.float32))
    out.close()
    os.replace(tmp, path)
    return path.name


def make_textures(folder: Path, res: int, seed: int = 7) -> dict:
    rng = np.random.default_rng(seed)
    y, x = np.meshgrid((np.arange(res) + 0.5) / res, (np.arange(res) + 0.5) / res, indexing="ij")
    # Lava: rock cells whose borders glow (distance to the nearest of a few periodic seeds).
    seeds = rng.uniform(0, 1, (14, 2))
    d = np.full((res, res, 2), np.inf)
    for sx, sy in seeds:
        dx = np.abs(x - sx)
        dy = np.abs(y - sy)
        dist = np.hypot(np.minimum(dx, 1 - dx), np.minimum(dy, 1 - dy))
        d[..., 1] = np.minimum(d[..., 1], np.maximum(d[..., 0], dist))
        d[..., 0] = np.minimum(d[..., 0], dist)
    crack = np.clip(1.0 - (d[..., 1] - d[..., 0]) / 0.035, 0, 1) ** 2
    rock = 0.08 + 0.06 * _mirror._smooth_noise(rng, res, 8)
    glow = crack[..., None] * np.array([4.0, 1.2, 0.15])
    # Leaf: an ellipse-like blade with serrated edges, veins darker; alpha 0 outside it.
    u, v = x - 0.5, y - 0.5
    r = np.hypot(u / 0.42, v / 0.22) * (1 + 0.06 * np.sin(np.arctan2(v, u) * 14))
    alpha = (r < 1.0).astype(np.float64)
    vein = np.exp(-(v / 0.01) ** 2) + 0.5 * np.exp(-((np.abs(u) * 0.5 - np.abs(v)) / 0.008) ** 2)
    green = np.array([0.12, 0.42, 0.08]) * (1 - 0.4 * np.clip(vein, 0, 1))[..., None]
    leaf = np.concatenate([np.where(alpha[..., None] > 0, green, 0.0), alpha[..., None]], -1)
    wear = _mirror._smooth_noise(rng, res, 5) ** 3
    files = _textured.save_textures(folder, {
        "rock": (rock[..., None].repeat(3, -1), "lava_rock.png"),
        "leaf": (leaf, "leaf_rgba.png"),
        "gold_roughness": ((0.03 + 0.22 * wear / max(float(wear.max()), 1e-6))[..., None], "gold_roughness.png"),
    })
    files["glow"] = _save_exr(folder / "lava_glow.exr", glow)
    return files


def _preview(stage, path: str):
    mat = UsdShade.Material.Define(stage, path)
    sh = UsdShade.Shader.Define(stage, f"{path}/surface")
    sh.CreateIdAttr("UsdPreviewSurface")
    mat.CreateSurfaceOutput().ConnectToSource(sh.CreateOutput("surface", Sdf.ValueTypeNames.Token))
    return mat, sh


def _texture(stage, mat_path: str, name: str, file: str, color_space: str, output: str, out_type):
    reader = stage.GetPrimAtPath(f"{mat_path}/st")
    if not reader:
        st = UsdShade.Shader.Define(stage, f"{mat_path}/st")
        st.CreateIdAttr("UsdPrimvarReader_float2")
        st.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
        st.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    tex = UsdShade.Shader.Define(stage, f"{mat_path}/{name}")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(f"./{file}"))
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(color_space)
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        UsdShade.Shader(stage.GetPrimAtPath(f"{mat_path}/st")).GetOutput("result"))
    return tex.CreateOutput(output, out_type)


def _quad(stage, path: str, material, corners):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(corners)
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set([(0, 0), (1, 0), (1, 1), (0, 1)])
    mesh.CreateDoubleSidedAttr(True)
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)


def build(folder: Path, res: int = 128) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    files = make_textures(folder, res)
    path = folder / "glow_and_leaves.usda"
    tmp = folder / "glow_and_leaves.tmp.usda"
    stage = Usd.Stage.CreateNew(str(tmp))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    f, c3, f3 = Sdf.ValueTypeNames.Float, Sdf.ValueTypeNames.Color3f, Sdf.ValueTypeNames.Float3

    lava, sh = _preview(stage, "/World/Looks/Lava")
    sh.CreateInput("diffuseColor", c3).ConnectToSource(
        _texture(stage, "/World/Looks/Lava", "rock_tex", files["rock"], "sRGB", "rgb", f3))
    sh.CreateInput("emissiveColor", c3).ConnectToSource(
        _texture(stage, "/World/Looks/Lava", "glow_tex", files["glow"], "raw", "rgb", f3))
    sh.CreateInput("roughness", f).Set(0.8)

    leaf, sh = _preview(stage, "/World/Looks/Leaf")
    sh.CreateInput("diffuseColor", c3).ConnectToSource(
        _texture(stage, "/World/Looks/Leaf", "leaf_tex", files["leaf"], "sRGB", "rgb", f3))
    sh.CreateInput("opacity", f).ConnectToSource(
        UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Leaf/leaf_tex")).CreateOutput("a", f))
    sh.CreateInput("opacityThreshold", f).Set(0.5)
    sh.CreateInput("roughness", f).Set(0.5)

    gold, sh = _preview(stage, "/World/Looks/Gold")
    sh.CreateInput("diffuseColor", c3).Set(Gf.Vec3f(1.0, 0.78, 0.34))
    sh.CreateInput("metallic", f).Set(1.0)
    sh.CreateInput("roughness", f).ConnectToSource(
        _texture(stage, "/World/Looks/Gold", "roughness_tex", files["gold_roughness"], "raw", "r", f))

    _quad(stage, "/World/Geo/LavaFloor", lava, [(-2, 0, 1.5), (2, 0, 1.5), (2, 0, -1.5), (-2, 0, -1.5)])
    _quad(stage, "/World/Geo/Leaf", leaf, [(-1.4, 0.1, 0.2), (0.2, 0.1, 0.2), (0.2, 1.3, 0.2), (-1.4, 1.3, 0.2)])
    _quad(stage, "/World/Geo/GoldPlate", gold, [(0.4, 0.0, -0.8), (1.8, 0.0, -0.8), (1.8, 1.2, -1.1),
                                                 (0.4, 1.2, -1.1)])
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(24.0)
    xf = UsdGeom.Xformable(cam)
    xf.AddTranslateOp().Set(Gf.Vec3d(0.0, 1.6, 4.2))
    xf.AddRotateXOp().Set(-18.0)
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(2.5)
    UsdGeom.Xformable(sun).AddRotateXYZOp().Set(Gf.Vec3f(-50.0, 30.0, 0.0))
    stage.GetRootLayer().Save()
    os.replace(tmp, path)
    return path


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("out", nargs="?", default=str(_here / "scene"))
    ap.add_argument("--res", type=int, default=128)
    a = ap.parse_args()
    print(f"wrote {build(Path(a.out), a.res)}")
