"""What a stage gives for rendering a material in place (mtlx2neural.scene.stage_render): the bound
triangles in world space, the first perspective camera and the distant/dome lights. Stages are
built in memory; no training, no rendering (well under a second)."""

from __future__ import annotations

import math

import numpy as np
import pytest

pxr = pytest.importorskip("pxr", reason="usd-core is needed to build the test stages")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux  # noqa: E402

from mtlx2neural.scene.stage_render import SPHERE_SEGMENTS, read_stage_view  # noqa: E402

# Values go through float32 attributes and float64 matrices: 1e-5 covers float32 rounding of
# numbers of size ~10.
TOL = 1e-5


def quad(stage, path="/World/Quad", st=True, translate=(0.0, 0.0, 0.0)):
    """A 2 x 2 quad in the z = 0 plane facing +z (counter-clockwise seen from +z), uv (0,0)-(1,1)."""
    m = UsdGeom.Mesh.Define(stage, path)
    m.GetPointsAttr().Set([Gf.Vec3f(*p) for p in ((-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0))])
    m.GetFaceVertexCountsAttr().Set([4])
    m.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    if st:
        UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex).Set(
            [Gf.Vec2f(*t) for t in ((0, 0), (1, 0), (1, 1), (0, 1))])
    UsdGeom.Xformable(m).AddTranslateOp().Set(Gf.Vec3d(*translate))
    return m


def stage_with_camera_and_lights(up="Y"):
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, up)
    quad(stage, translate=(0.0, 0.0, 1.0))
    cam = UsdGeom.Camera.Define(stage, "/World/Cam")  # looks down its -z from (0, 0, 10)
    cam.GetFocalLengthAttr().Set(50.0)
    cam.GetHorizontalApertureAttr().Set(36.0)
    cam.GetVerticalApertureAttr().Set(24.0)
    UsdGeom.Xformable(cam).AddTranslateOp().Set(Gf.Vec3d(0, 0, 10))
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(2.0)
    sun.CreateExposureAttr(1.0)
    sun.CreateColorAttr(Gf.Vec3f(1.0, 0.5, 0.25))
    UsdGeom.Xformable(sun).AddRotateYOp().Set(90.0)  # its +z turns to +x: it shines along -x
    UsdLux.SphereLight.Define(stage, "/World/Bulb")
    return stage


def test_camera_light_and_mesh_values():
    view = read_stage_view(stage_with_camera_and_lights(), ["/World/Quad"])
    assert view.prims == ["/World/Quad"] and view.positions.shape == (2, 3, 3) and view.up_axis == "Y"
    # World positions: the quad translated to z = 1; normals +z; uvs as authored.
    assert np.allclose(view.positions[..., 2], 1.0, atol=TOL)
    assert np.allclose(view.normals, [0, 0, 1], atol=TOL)
    assert view.uvs.min() == 0.0 and view.uvs.max() == 1.0
    cam = view.camera
    assert cam.path == "/World/Cam"
    assert np.allclose(cam.position, [0, 0, 10], atol=TOL)
    assert np.allclose(cam.forward, [0, 0, -1], atol=TOL) and np.allclose(cam.up, [0, 1, 0], atol=TOL)
    # The square image is the centre square of the 36 x 24 frame: the vertical aperture's angle.
    assert cam.fov == pytest.approx(math.degrees(2 * math.atan(24 / 100)), abs=1e-4)
    (sun,) = view.lights
    assert sun.path == "/World/Sun" and sun.kind == "distant"
    assert np.allclose(sun.direction, [1, 0, 0], atol=TOL)  # towards the light: +x
    assert np.allclose(sun.rgb, [4.0, 2.0, 1.0], atol=TOL)  # intensity 2 x 2^exposure 1 x colour
    assert any(n.startswith("/World/Bulb: SphereLight") and "ignored" in n for n in view.notes)


def test_z_up_stage_turns_to_y_up():
    view = read_stage_view(stage_with_camera_and_lights(up="Z"), ["/World/Quad"])
    # (x, y, z) -> (x, z, -y): the camera at z = 10 is now 10 up, looking down.
    assert view.up_axis == "Z"
    assert np.allclose(view.camera.position, [0, 10, 0], atol=TOL)
    assert np.allclose(view.camera.forward, [0, -1, 0], atol=TOL)
    assert np.allclose(view.normals, [0, 1, 0], atol=TOL)
    assert np.allclose(view.lights[0].direction, [1, 0, 0], atol=TOL)  # x is unchanged


def test_sphere_gprims_meshes_without_uvs_and_other_gprims():
    stage = Usd.Stage.CreateInMemory()
    ball = UsdGeom.Sphere.Define(stage, "/World/Ball")
    ball.GetRadiusAttr().Set(2.0)
    UsdGeom.Xformable(ball).AddTranslateOp().Set(Gf.Vec3d(5, 0, 0))
    quad(stage, "/World/Bare", st=False)
    UsdGeom.Cube.Define(stage, "/World/Box")
    view = read_stage_view(stage, ["/World/Ball", "/World/Bare", "/World/Box"])
    assert view.prims == ["/World/Ball", "/World/Bare"] and view.camera is None and view.lights == []
    nu, nv = SPHERE_SEGMENTS
    ball_tris = 2 * nu * nv
    assert len(view.positions) == ball_tris + 2
    p, n = view.positions[:ball_tris], view.normals[:ball_tris]
    assert np.allclose(np.linalg.norm(p - [5, 0, 0], axis=-1), 2.0, atol=TOL)  # on the radius-2 sphere
    assert np.allclose(n, (p - [5, 0, 0]) / 2.0, atol=TOL)  # outward unit normals
    # The renderer's layout: v from the south pole, u around y.
    assert np.allclose(view.uvs[:ball_tris, :, 1], np.arccos(-n[..., 1].clip(-1, 1)) / math.pi, atol=1e-4)
    assert np.all(view.uvs[ball_tris:] == 0)  # no st: uv 0
    assert any(n.startswith("/World/Box: not a mesh (Cube)") for n in view.notes)


def test_dome_light_texture_and_invisible_lights(tmp_path):
    stage = Usd.Stage.CreateInMemory()
    quad(stage)
    dome = UsdLux.DomeLight.Define(stage, "/World/Dome")
    dome.CreateTextureFileAttr(Sdf.AssetPath(str(tmp_path / "sky.exr")))
    dome.CreateIntensityAttr(0.5)
    off = UsdLux.DistantLight.Define(stage, "/World/Off")
    UsdGeom.Imageable(off).MakeInvisible()
    (light,) = read_stage_view(stage, ["/World/Quad"]).lights
    assert light.kind == "dome" and light.texture.endswith("sky.exr") and light.rgb == (0.5, 0.5, 0.5)
