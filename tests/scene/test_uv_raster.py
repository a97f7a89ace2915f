"""The bound meshes rasterised into their UV layout (mtlx2neural.scene.uv_raster)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

pxr = pytest.importorskip("pxr", reason="usd-core is needed to build the test stages")
from pxr import Gf, Sdf, Usd, UsdGeom  # noqa: E402

from mtlx2neural.scene.uv_raster import (  # noqa: E402
    SPHERE,
    GeometrySource,
    rasterise_meshes,
    sphere_maps,
)

# Values are interpolated in float64 and stored as float32: exact affine functions of uv come back
# within float32 rounding of numbers of size ~10, so 1e-5 absolute.
TOL = 1e-5


def quad(stage, path="/World/Quad", points=((0, 0, 0), (2, 0, 0), (2, 3, 0), (0, 3, 0)),
         st=((0, 0), (1, 0), (1, 1), (0, 1)), translate=(10.0, 0.0, 0.0), colors=None):
    """A one-polygon mesh (fan-triangulated as (0,1,2), (0,2,3)) with vertex UVs ``st``."""
    m = UsdGeom.Mesh.Define(stage, path)
    m.GetPointsAttr().Set([Gf.Vec3f(*p) for p in points])
    m.GetFaceVertexCountsAttr().Set([len(points)])
    m.GetFaceVertexIndicesAttr().Set(list(range(len(points))))
    if st is not None:
        UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                             UsdGeom.Tokens.vertex).Set([Gf.Vec2f(*t) for t in st])
    if colors is not None:
        UsdGeom.PrimvarsAPI(m).CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray,
                                             UsdGeom.Tokens.vertex).Set([Gf.Vec3f(*c) for c in colors])
    if translate is not None:
        UsdGeom.Xformable(m).AddTranslateOp().Set(Gf.Vec3d(*translate))
    return m


def texel_uv(h, w):
    """[H, W] u and v of the texel centres, row 0 at v = 1 (the maps' layout)."""
    u = (np.arange(w) + 0.5) / w
    v = 1.0 - (np.arange(h) + 0.5) / h
    return np.meshgrid(u, v)


def test_quad_position_normal_tangent_at_texel_centres():
    stage = Usd.Stage.CreateInMemory()
    quad(stage)
    g = rasterise_meshes(stage, ["/World/Quad"], (6, 8))
    u, v = texel_uv(6, 8)
    assert bool(g.covered.all())
    expected = np.stack([2 * u, 3 * v, np.zeros_like(u)])  # the quad maps uv affinely onto [0,2] x [0,3]
    assert np.allclose(g.maps["position:object"].numpy(), expected, atol=TOL)
    assert np.allclose(g.maps["position:world"].numpy(), expected + np.array([10.0, 0, 0])[:, None, None], atol=TOL)
    for key, axis in (("normal", (0, 0, 1)), ("tangent", (1, 0, 0)), ("bitangent", (0, 1, 0))):
        for space in ("object", "world"):
            got = g.maps[f"{key}:{space}"].numpy()
            assert np.allclose(got, np.array(axis, dtype=float)[:, None, None], atol=TOL), (key, space)


def test_world_space_follows_rotation_and_scale():
    stage = Usd.Stage.CreateInMemory()
    m = quad(stage, translate=None)
    xf = UsdGeom.Xformable(m)
    xf.AddRotateXOp().Set(90.0)  # object +y -> world +z, object +z (the normal) -> world -y
    xf.AddScaleOp().Set(Gf.Vec3f(1, 2, 1))
    g = rasterise_meshes(stage, ["/World/Quad"], (4, 4))
    u, v = texel_uv(4, 4)
    want = np.stack([2 * u, np.zeros_like(u), 6 * v])  # y scaled by 2 then rotated onto z
    assert np.allclose(g.maps["position:world"].numpy(), want, atol=1e-4)  # float32 rotation matrix: 1e-4
    assert np.allclose(g.maps["normal:world"].numpy(), np.array([0, -1.0, 0])[:, None, None], atol=1e-5)
    assert np.allclose(g.maps["bitangent:world"].numpy(), np.array([0, 0, 1.0])[:, None, None], atol=1e-5)


def test_display_color_interpolated_per_triangle():
    stage = Usd.Stage.CreateInMemory()
    colors = np.array([(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 1)], dtype=float)
    quad(stage, colors=colors)
    g = rasterise_meshes(stage, ["/World/Quad"], (8, 8), primvars=["displayColor"])
    u, v = texel_uv(8, 8)
    # Fan triangles (0,1,2) below the diagonal u = v and (0,2,3) above it: barycentric weights in uv.
    lower = u >= v
    w = np.where(lower[None], np.stack([1 - u, u - v, v, np.zeros_like(u)]),
                 np.stack([1 - v, np.zeros_like(u), u, v - u]))
    want = np.einsum("kij,kc->cij", w, colors)
    assert np.allclose(g.maps["primvar:displayColor"].numpy(), want, atol=TOL)


def test_uncovered_texels_take_the_nearest_covered_value():
    stage = Usd.Stage.CreateInMemory()
    # One triangle over the lower-left half of UV space.
    quad(stage, points=((0, 0, 0), (1, 0, 0), (0, 1, 0)), st=((0, 0), (1, 0), (0, 1)), translate=None)
    g = rasterise_meshes(stage, ["/World/Quad"], (8, 8))
    u, v = texel_uv(8, 8)
    cov = g.covered.numpy()
    # Centres inside are covered, outside not; those exactly on the hypotenuse go by the edge rule.
    assert cov[(u + v) < 1].all() and not cov[(u + v) > 1].any()
    pos = g.maps["position:object"].numpy()
    assert np.all(np.isfinite(pos)) and np.allclose(pos[2], 0.0)
    for r, c in [(0, 7), (1, 6), (0, 4)]:  # uncovered: equal to some covered texel at the least distance
        assert not cov[r, c]
        rr, cc = np.nonzero(cov)
        d = (rr - r) ** 2 + (cc - c) ** 2
        nearest = [(a, b) for a, b, dd in zip(rr, cc, d) if dd == d.min()]
        assert any(np.allclose(pos[:, r, c], pos[:, a, b]) for a, b in nearest)


def test_shared_diagonal_is_not_an_overlap_and_covers_every_texel_once():
    stage = Usd.Stage.CreateInMemory()
    quad(stage, translate=None)  # texel centres lie exactly on the fan's diagonal at a square grid
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an overlap warning would raise
        g = rasterise_meshes(stage, ["/World/Quad"], (4, 4))
    assert bool(g.covered.all()) and not g.warnings


def test_overlapping_uvs_within_one_mesh_warn_naming_the_prim():
    stage = Usd.Stage.CreateInMemory()
    m = UsdGeom.Mesh.Define(stage, "/World/Folded")
    m.GetPointsAttr().Set([(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (0, 1, 1)])
    m.GetFaceVertexCountsAttr().Set([3, 3])
    m.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3, 4, 5])
    UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex).Set(
        [(0, 0), (1, 0), (0, 1)] * 2)  # both triangles on the same UV half
    with pytest.warns(UserWarning, match="/World/Folded: overlapping UVs"):
        g = rasterise_meshes(stage, ["/World/Folded"], (8, 8))
    u, v = texel_uv(8, 8)
    # The first triangle drawn keeps a texel: z = 0 there, not the second's z = 1.
    assert np.allclose(g.maps["position:object"].numpy()[2][(u + v) <= 1], 0.0)


def test_overlap_between_two_meshes_is_normal_and_the_first_wins():
    stage = Usd.Stage.CreateInMemory()
    quad(stage, "/World/A", translate=None)
    quad(stage, "/World/B", translate=(0, 0, 5))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        g = rasterise_meshes(stage, ["/World/A", "/World/B"], (4, 4))
    assert g.prims == ["/World/A", "/World/B"]
    assert np.allclose(g.maps["position:world"].numpy()[2], 0.0)


def test_missing_uvs_warn_naming_the_prim_and_the_sphere_fallback():
    stage = Usd.Stage.CreateInMemory()
    quad(stage, "/World/NoUV", st=None)
    with pytest.warns(UserWarning) as record:
        g = rasterise_meshes(stage, ["/World/NoUV"], (4, 8))
    text = " ".join(str(r.message) for r in record)
    assert "/World/NoUV" in text and "no UVs" in text and "unit sphere" in text
    assert g.prims == [SPHERE]


def test_sphere_maps_follow_the_renderers_spherical_layout():
    g = sphere_maps((16, 32))
    p = g.maps["position:object"].numpy()
    u, v = texel_uv(16, 32)
    assert np.allclose(np.linalg.norm(p, axis=0), 1.0, atol=1e-6)
    # render.geometry.Sphere: u = 0.5 + atan2(x, z) / 2pi, v = acos(-y) / pi (float32: 1e-5).
    assert np.allclose(0.5 + np.arctan2(p[0], p[2]) / (2 * math.pi), u, atol=1e-5)
    assert np.allclose(np.arccos(-p[1]) / math.pi, v, atol=1e-5)
    assert np.allclose(g.maps["normal:world"].numpy(), p, atol=1e-6)
    t, n = g.maps["tangent:object"].numpy(), g.maps["normal:object"].numpy()
    assert np.allclose((t * n).sum(0), 0.0, atol=1e-6)
    dpdu = np.gradient(p, axis=2)  # tangent along increasing u
    assert np.all((t * dpdu).sum(0) > 0)


def test_maps_sample_bilinear_and_exact_at_texel_centres():
    g = sphere_maps((8, 8))
    u, v = texel_uv(8, 8)
    uv = torch.tensor(np.stack([u.ravel(), v.ravel()], -1), dtype=torch.float32)
    got = g.sample(uv, ["position:world"])["position:world"]
    assert torch.allclose(got.T.reshape(3, 8, 8), g.maps["position:world"], atol=1e-6)


def test_geometry_source_caches_per_resolution_and_names_its_origin(tmp_path):
    stage = Usd.Stage.CreateNew(str(tmp_path / "quad.usda"))
    quad(stage)
    stage.GetRootLayer().Save()
    src = GeometrySource(str(tmp_path / "quad.usda"), ["/World/Quad"])
    assert not src.is_sphere and src.describe() == "mesh prims /World/Quad"
    a = src.maps((4, 4))
    assert src.maps((4, 4)) is a and src.maps((2, 2)).resolution == (2, 2)
    assert GeometrySource(None, []).describe() == SPHERE
