"""Write the bundled sample stage ``samples/layered_spheres.usda``.

Run:  python samples/make_samples.py

The stage holds real UsdShade networks of both kinds mtlx2neural reads:
- /World/Looks/CarPaint: a MaterialX standard_surface (coat over a metallic base);
- /World/Looks/Plastic: a UsdPreviewSurface network;
- /World/Looks/Hidden: bound only to an invisible prim (skipped);
- /World/Looks/Unused: bound to nothing (skipped).
"""

from __future__ import annotations

import os
import sys

from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade


def _mtlx_material(stage, path, **inputs):
    mat = UsdShade.Material.Define(stage, path)
    sh = UsdShade.Shader.Define(stage, f"{path}/Surface")
    sh.CreateIdAttr("ND_standard_surface_surfaceshader")
    for name, (value, vtype) in inputs.items():
        sh.CreateInput(name, vtype).Set(value)
    out = sh.CreateOutput("out", Sdf.ValueTypeNames.Token)
    mat.CreateSurfaceOutput("mtlx").ConnectToSource(out)
    return mat


def _preview_material(stage, path, color, roughness):
    mat = UsdShade.Material.Define(stage, path)
    sh = UsdShade.Shader.Define(stage, f"{path}/Preview")
    sh.CreateIdAttr("UsdPreviewSurface")
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(color)
    sh.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(roughness)
    out = sh.CreateOutput("surface", Sdf.ValueTypeNames.Token)
    mat.CreateSurfaceOutput().ConnectToSource(out)
    return mat


def build(path: str) -> None:
    stage = Usd.Stage.CreateNew(path + ".tmp.usda")
    stage.SetMetadata("comment", "mtlx2neural sample, written by samples/make_samples.py")
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    f3, c3 = Sdf.ValueTypeNames.Float, Sdf.ValueTypeNames.Color3f
    paint = _mtlx_material(stage, "/World/Looks/CarPaint",
                           base_color=(Gf.Vec3f(0.55, 0.05, 0.04), c3), metalness=(0.6, f3),
                           specular_roughness=(0.35, f3), coat=(1.0, f3), coat_roughness=(0.08, f3))
    plastic = _preview_material(stage, "/World/Looks/Plastic", Gf.Vec3f(0.2, 0.35, 0.6), 0.45)
    hidden = _mtlx_material(stage, "/World/Looks/Hidden", base_color=(Gf.Vec3f(0.1, 0.8, 0.1), c3))
    _mtlx_material(stage, "/World/Looks/Unused", base_color=(Gf.Vec3f(0.9, 0.9, 0.1), c3))

    sphere = UsdGeom.Sphere.Define(stage, "/World/Geo/Sphere")
    sphere.CreateRadiusAttr(1.0)
    floor = UsdGeom.Mesh.Define(stage, "/World/Geo/Floor")
    floor.CreatePointsAttr([(-5, -1, -5), (5, -1, -5), (5, -1, 5), (-5, -1, 5)])
    floor.CreateFaceVertexCountsAttr([4])
    floor.CreateFaceVertexIndicesAttr([0, 3, 2, 1])
    ghost = UsdGeom.Sphere.Define(stage, "/World/Geo/Ghost")
    ghost.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    for prim, mat in ((sphere, paint), (floor, plastic), (ghost, hidden)):
        UsdShade.MaterialBindingAPI.Apply(prim.GetPrim()).Bind(mat)
    stage.GetRootLayer().Save()
    os.replace(path + ".tmp.usda", path)  # atomic: never leave a half-written sample


if __name__ == "__main__":
    out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(os.path.abspath(__file__)),
                                                              "layered_spheres.usda")
    build(out)
    print(f"wrote {out}")
