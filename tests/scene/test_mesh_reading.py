"""scene/mesh_reading.py: the one reader of bound meshes, on real USD stages built in memory."""

from __future__ import annotations

import numpy as np
import pytest

pxr = pytest.importorskip("pxr", reason="usd-core is a core dependency; without it no stage can be read")
from pxr import Gf, Sdf, Usd, UsdGeom, Vt  # noqa: E402

from mtlx2neural.scene.mesh_reading import (  # noqa: E402
    fan_triangles,
    mesh_triangles,
    object_to_world,
    read_topology,
    uv_primvar,
)


def _stage(uv_name="st", how=UsdGeom.Tokens.faceVarying, holes=(), left=False):
    """A quad (0..1 in x, y) and a triangle beside it, translated by (10, 0, 0); uv = xy."""
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.Xform.Define(stage, "/W").AddTranslateOp().Set(Gf.Vec3d(10, 0, 0))
    mesh = UsdGeom.Mesh.Define(stage, "/W/M")
    pts = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0)]
    mesh.GetPointsAttr().Set(Vt.Vec3fArray([Gf.Vec3f(*p) for p in pts]))
    mesh.GetFaceVertexCountsAttr().Set([4, 3])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3, 1, 4, 2])
    if holes:
        mesh.GetHoleIndicesAttr().Set(list(holes))
    if left:
        mesh.GetOrientationAttr().Set(UsdGeom.Tokens.leftHanded)
    if uv_name:
        idx = [0, 1, 2, 3, 1, 4, 2] if how == UsdGeom.Tokens.faceVarying else list(range(5))
        pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(uv_name, Sdf.ValueTypeNames.TexCoord2fArray, how)
        pv.Set(Vt.Vec2fArray([Gf.Vec2f(pts[i][0] / 2, pts[i][1]) for i in idx]))
    subset = UsdGeom.Subset.Define(stage, "/W/M/Tri")
    subset.GetIndicesAttr().Set([1])
    subset.GetElementTypeAttr().Set(UsdGeom.Tokens.face)
    UsdGeom.Sphere.Define(stage, "/W/Ball")
    return stage


def test_fan_triangles_of_kept_polygons():
    tris = fan_triangles(np.array([4, 3, 5]), np.array([True, False, True]))
    # quad at face-vertices 0..3 -> (0,1,2), (0,2,3); the pentagon starts at 7 -> 3 triangles
    assert tris.tolist() == [[0, 1, 2], [0, 2, 3], [7, 8, 9], [7, 9, 10], [7, 10, 11]]
    assert fan_triangles(np.array([3]), np.array([False])).shape == (0, 3)


def test_topology_subset_holes_and_uv_set():
    stage = _stage(uv_name="map1", holes=(0,))
    whole = read_topology(stage, "/W/M")
    assert whole.keep.tolist() == [True, True] and whole.holes.tolist() == [True, False]
    assert whole.uv_how == "faceVarying" and whole.uv.shape == (7, 2) and whole.uv_count_error() is None
    assert str(uv_primvar(whole.mesh).GetPrimvarName()) == "map1"  # no st: the first texCoord2 primvar
    sub = read_topology(stage, "/W/M/Tri")
    assert sub.subset and sub.keep.tolist() == [False, True]
    np.testing.assert_array_equal(object_to_world(stage, "/W/M/Tri")[3, :3], [10, 0, 0])


@pytest.mark.parametrize("path, edit, reason", [
    ("/W/Nope", None, "no such prim"),
    ("/W/Ball", None, "not a mesh (Sphere)"),
    ("/W/M", lambda s: UsdGeom.Mesh.Get(s, "/W/M").GetFaceVertexIndicesAttr().Set([0, 1, 2, 3, 1, 4, 9]),
     "malformed topology"),
    ("/W/M/Tri", lambda s: UsdGeom.Subset.Get(s, "/W/M/Tri").GetElementTypeAttr().Set(UsdGeom.Tokens.point),
     "GeomSubset of non-face elements"),
])
def test_unreadable_prims_give_a_reason(path, edit, reason):
    stage = _stage()
    if edit:
        edit(stage)
    found = read_topology(stage, path)
    assert isinstance(found, str) and found.startswith(reason)


def test_mesh_triangles_corners():
    stage = _stage(how=UsdGeom.Tokens.vertex)
    tuv, corners = mesh_triangles(stage, "/W/M", ())
    assert tuv.shape == (3, 3, 2) and corners["position:world"].shape == (3, 3, 3)
    np.testing.assert_allclose(corners["position:world"] - corners["position:object"], np.broadcast_to([10, 0, 0], (3, 3, 3)))
    # counter-clockwise in xy, right-handed: +z normals; uv = (x/2, y): tangent +x, bitangent +y
    np.testing.assert_allclose(corners["normal:world"], np.broadcast_to([0, 0, 1], (3, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(corners["tangent:world"], np.broadcast_to([1, 0, 0], (3, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(corners["bitangent:world"], np.broadcast_to([0, 1, 0], (3, 3, 3)), atol=1e-12)
    _, flipped = mesh_triangles(_stage(how=UsdGeom.Tokens.vertex, left=True), "/W/M", ())
    np.testing.assert_allclose(flipped["normal:object"][..., 2], -1.0)


def test_mesh_without_uvs():
    stage = _stage(uv_name=None)
    assert mesh_triangles(stage, "/W/M", ()).startswith("no UVs (no st primvar")
    tuv, _ = mesh_triangles(stage, "/W/M", (), need_uv=False)  # rendering: uv 0
    assert tuv.shape == (3, 3, 2) and not tuv.any()
