"""``--texel-density``: metres per UV unit measured on real USD meshes, and the grid the plan derives.

Stages are built with ``pxr`` in ``tmp_path``. Tolerances: points and UVs are stored as
float32 but every value used here (0.5, 1, 2, 3, 0.25 ...) is exact in float32, and the
areas are summed in float64, so the measured values match the analytic ones to ~1e-12;
``rel=1e-9`` leaves room for the transform's float64 matrix product and stays far below
anything that could move a ceil() in the grid tests (their products are whole numbers
or at least 0.25 away from one).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from mtlx2neural.cli import main
from mtlx2neural.pipeline.plan import latent_resolution, plan_materials
from mtlx2neural.scene import load_asset
from mtlx2neural.scene.texel_density import surface_density, texels_per_uv
from mtlx2neural.train.config import preset

TINY = preset("fast", iterations=20, batch=256)
REL = 1e-9  # see the module docstring

QUAD_POINTS = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]  # unit square, scaled by the caller
QUAD_UV = [(0, 0), (1, 0), (1, 1), (0, 1)]


def new_stage(path: Path, meters_per_unit: float | None = 1.0):
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(path))
    if meters_per_unit is not None:
        UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    UsdGeom.Xform.Define(stage, "/World")
    return stage


def add_mesh(stage, path: str, points, counts, indices, uv=None, interpolation="vertex", uv_indices=None,
             uv_name="st", translate=None, scale=None):
    from pxr import Gf, Sdf, UsdGeom

    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr([Gf.Vec3f(*p) for p in points])
    mesh.CreateFaceVertexCountsAttr(counts)
    mesh.CreateFaceVertexIndicesAttr(indices)
    if translate is not None:
        mesh.AddTranslateOp().Set(Gf.Vec3d(*translate))
    if scale is not None:
        mesh.AddScaleOp().Set(Gf.Vec3f(*scale))
    if uv is not None:
        pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(uv_name, Sdf.ValueTypeNames.TexCoord2fArray, interpolation)
        pv.Set([Gf.Vec2f(*t) for t in uv])
        if uv_indices is not None:
            pv.SetIndices(uv_indices)
    return mesh


def quad(stage, path: str, size: float, **kw):
    return add_mesh(stage, path, [(x * size, y * size, z) for x, y, z in QUAD_POINTS], [4], [0, 1, 2, 3],
                    uv=QUAD_UV, **kw)


# ----------------------------------------------------------------------------- metres per UV unit


@pytest.mark.parametrize("mpu, expected", [(1.0, 2.0), (0.01, 0.02), (None, 0.02)])
def test_two_metre_quad_with_unit_uvs(tmp_path, mpu, expected):
    """2 x 2 stage units over UV [0,1]^2: 2 m per UV unit in metres, 0.02 in centimetres (USD's default)."""
    stage = new_stage(tmp_path / "q.usda", mpu)
    quad(stage, "/World/Q", 2.0)
    d = surface_density(stage, ["/World/Q"])
    assert d.skipped == [] and [m.prim for m in d.meshes] == ["/World/Q"]
    assert d.metres_per_uv == pytest.approx(expected, rel=REL)
    assert d.meshes[0].world_area_m2 == pytest.approx(expected**2, rel=REL) and d.meshes[0].uv_area == 1.0
    assert d.meters_per_unit == (mpu or 0.01) and d.unit_authored == (mpu is not None)


def test_face_varying_indexed_st_and_world_transform(tmp_path):
    """Two quads side by side, faceVarying st through indices, the mesh scaled x3 and moved: the
    world-space area (not the local one) counts, and each face-vertex takes its indexed UV."""
    stage = new_stage(tmp_path / "fv.usda")
    points = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 0), (1, 1, 0), (2, 1, 0)]
    # Each quad maps onto half of UV space: [0,0.5]x[0,1] and [0.5,1]x[0,1] -> UV area 1 in all.
    uv_values = [(0, 0), (0.5, 0), (1, 0), (0, 1), (0.5, 1), (1, 1)]
    add_mesh(stage, "/World/M", points, [4, 4], [0, 1, 4, 3, 1, 2, 5, 4], uv=uv_values,
             interpolation="faceVarying", uv_indices=[0, 1, 4, 3, 1, 2, 5, 4], translate=(5, -2, 7),
             scale=(3, 3, 3))
    d = surface_density(stage, ["/World/M"])
    m = d.meshes[0]
    # local area 2 m^2, scaled x3 on both axes: 18 m^2 over one UV unit -> sqrt(18) m per UV unit
    assert m.world_area_m2 == pytest.approx(18.0, rel=REL) and m.uv_area == pytest.approx(1.0, rel=REL)
    assert d.metres_per_uv == pytest.approx(math.sqrt(18.0), rel=REL)
    # The same mesh with the UV indices swapped between the quads' corners folds UV space: the
    # indices are really applied (a non-indexed read would give a different UV area).
    add_mesh(stage, "/World/Folded", points, [4, 4], [0, 1, 4, 3, 1, 2, 5, 4], uv=uv_values,
             interpolation="faceVarying", uv_indices=[0, 1, 4, 3, 0, 1, 4, 3])
    assert surface_density(stage, ["/World/Folded"]).meshes[0].uv_area == pytest.approx(1.0, rel=REL)
    add_mesh(stage, "/World/Squashed", points, [4, 4], [0, 1, 4, 3, 1, 2, 5, 4], uv=uv_values,
             interpolation="faceVarying", uv_indices=[0, 1, 1, 0, 1, 2, 5, 4])
    assert surface_density(stage, ["/World/Squashed"]).meshes[0].uv_area == pytest.approx(0.5, rel=REL)


def test_polygons_are_fan_triangulated(tmp_path):
    """A regular hexagon of side 1 (area 3*sqrt(3)/2) with UVs = points / 4: 4 m per UV unit."""
    stage = new_stage(tmp_path / "hex.usda")
    pts = [(math.cos(k * math.pi / 3), math.sin(k * math.pi / 3), 0) for k in range(6)]
    add_mesh(stage, "/World/H", pts, [6], list(range(6)), uv=[(x / 4, y / 4) for x, y, _ in pts])
    m = surface_density(stage, ["/World/H"]).meshes[0]
    # float32 points (cos/sin are not exact in float32): 1e-6
    assert m.world_area_m2 == pytest.approx(3 * math.sqrt(3) / 2, rel=1e-6)
    assert m.metres_per_uv == pytest.approx(4.0, rel=1e-6)


def test_geom_subset_measures_only_its_faces(tmp_path):
    """A mesh of a 1x1 quad and a 3x3 quad, each over the whole UV square; a subset of the big face."""
    from pxr import UsdGeom, UsdShade

    stage = new_stage(tmp_path / "sub.usda")
    points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (10, 0, 0), (13, 0, 0), (13, 3, 0), (10, 3, 0)]
    uv = QUAD_UV + QUAD_UV
    mesh = add_mesh(stage, "/World/M", points, [4, 4], [0, 1, 2, 3, 4, 5, 6, 7], uv=uv)
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).CreateMaterialBindSubset("big", [1], UsdGeom.Tokens.face)
    UsdShade.MaterialBindingAPI(mesh.GetPrim()).CreateMaterialBindSubset("small", [0], UsdGeom.Tokens.face)
    assert surface_density(stage, ["/World/M/big"]).metres_per_uv == pytest.approx(3.0, rel=REL)
    assert surface_density(stage, ["/World/M/small"]).metres_per_uv == pytest.approx(1.0, rel=REL)
    whole = surface_density(stage, ["/World/M"]).meshes[0]  # 10 m^2 over 2 UV units
    assert whole.metres_per_uv == pytest.approx(math.sqrt(5.0), rel=REL)
    both = surface_density(stage, ["/World/M/small", "/World/M/big"])  # the most demanding decides
    assert both.metres_per_uv == pytest.approx(3.0, rel=REL)


def test_unusable_prims_are_skipped_with_a_reason(tmp_path):
    from pxr import UsdGeom

    stage = new_stage(tmp_path / "bad.usda")
    add_mesh(stage, "/World/NoUV", QUAD_POINTS, [4], [0, 1, 2, 3])
    add_mesh(stage, "/World/Flat", QUAD_POINTS, [4], [0, 1, 2, 3], uv=[(0.5, 0.5)] * 4)
    UsdGeom.Sphere.Define(stage, "/World/Ball")
    add_mesh(stage, "/World/OtherName", QUAD_POINTS, [4], [0, 1, 2, 3], uv=[(0, 0), (2, 0), (2, 2), (0, 2)],
             uv_name="UVMap")  # no st: the first texCoord2f[] primvar is used
    d = surface_density(stage, ["/World/NoUV", "/World/Flat", "/World/Ball", "/World/OtherName"])
    reasons = dict(d.skipped)
    assert "no st primvar" in reasons["/World/NoUV"]
    assert "span no area" in reasons["/World/Flat"]
    assert reasons["/World/Ball"].startswith("not a mesh")
    assert [m.prim for m in d.meshes] == ["/World/OtherName"] and d.metres_per_uv == pytest.approx(0.5, rel=REL)
    nothing = surface_density(stage, ["/World/NoUV", "/World/Ball"])
    assert nothing.metres_per_uv is None and "no bound mesh has usable UVs" in nothing.reason()
    assert "no prims are bound" in surface_density(stage, []).reason()


def test_texels_per_uv_rounds_up_but_forgives_float_noise():
    assert texels_per_uv(512, 0.02) == 11  # 10.24 texels: 11 keep the density
    assert texels_per_uv(512, 0.25) == 128
    assert texels_per_uv(100, 0.07) == 7  # 7.000000000000001 in floating point
    assert texels_per_uv(1, 1e-6) == 1


# ----------------------------------------------------------------------------- the plan's grid


def write_png(path: Path, size: int) -> None:
    import OpenImageIO as oiio

    img = (np.random.default_rng(0).random((size, size, 3)) * 255).astype(np.uint8)
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(size, size, 3, "uint8"))
    out.write_image(img)
    out.close()


def textured_scene(folder: Path, sizes: dict[str, float], tex: int = 64, uniform: bool = False) -> Path:
    """One quad per material (``sizes``: material name -> quad side in metres), each material
    an identical standard_surface whose base colour is a ``tex`` x ``tex`` texture (or a constant)."""
    from pxr import Gf, Sdf, UsdShade

    write_png(folder / "albedo.png", tex)
    path = folder / "scene.usda"
    stage = new_stage(path)
    for name, side in sizes.items():
        mat = UsdShade.Material.Define(stage, f"/World/Looks/{name}")
        sh = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/surface")
        sh.CreateIdAttr("ND_standard_surface_surfaceshader")
        if uniform:
            sh.CreateInput("base_color", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.5, 0.2, 0.1))
        else:
            img = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/albedo")
            img.CreateIdAttr("ND_image_color3")
            img.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath("./albedo.png"))
            sh.CreateInput("base_color", Sdf.ValueTypeNames.Color3f).ConnectToSource(
                img.CreateOutput("out", Sdf.ValueTypeNames.Color3f))
        mat.CreateSurfaceOutput("mtlx").ConnectToSource(sh.CreateOutput("out", Sdf.ValueTypeNames.Token))
        mesh = quad(stage, f"/World/Geo_{name}", side, translate=(10 * len(name), 0, 0))
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    stage.GetRootLayer().Save()
    return path


def plan(asset, density, cfg=TINY):
    return plan_materials(load_asset(asset).materials, cfg, texel_density=density, asset=asset)


def test_density_below_the_textures_scales_the_grid_down_and_warns(tmp_path):
    asset = textured_scene(tmp_path, {"A": 2.0})  # 2 m per UV unit, 64x64 texture
    base = plan(asset, None)[0]
    assert base.grid_kind == "native" and base.grid == (64, 64) and base.notes == []
    p = plan(asset, 8.0)[0]  # 8 texels/m x 2 m = 16 texels per UV unit < 64
    assert p.metres_per_uv == pytest.approx(2.0, rel=REL) and p.density_texels == 16
    assert p.grid_kind == "density" and p.grid == (16, 16) and p.texture_grid == (64, 64)
    assert latent_resolution(p.compiled, p.cfg) == p.grid  # the settings it trains with give that grid
    assert p.cfg.max_resolution == 16 and TINY.max_resolution == 256
    [w] = p.warnings
    assert w.startswith("/World/Looks/A: latent grid 16x16 from the scene's texel density (8 texels/m x 2 m per "
                        "UV unit = 16 texels per UV unit) is below the textures' 64x64")
    assert "raise --texel-density (at least 32 keeps the textures' grid) or omit it" in w
    assert "from the scene's texel density" in p.grid_text()
    assert p.digest != base.digest and p.content != base.content  # the cache key follows the grid
    assert plan(asset, 4.0)[0].digest not in (p.digest, base.digest)  # 8x8: another grid, another key


def test_density_at_or_above_the_textures_keeps_native(tmp_path):
    asset = textured_scene(tmp_path, {"A": 2.0})
    base = plan(asset, None)[0]
    for density, implied in ((32.0, 64), (100.0, 200)):
        p = plan(asset, density)[0]
        assert p.grid_kind == "native" and p.grid == (64, 64) and p.density_texels == implied
        assert p.warnings == [] and "never upsampled" in p.notes[0] and "never upsampled" in p.grid_text()
        assert p.digest == base.digest and p.cfg == TINY  # same grid: the cached result stays valid


def test_max_texels_still_caps_after_the_density(tmp_path):
    asset = textured_scene(tmp_path, {"A": 2.0})
    capped = plan(asset, 8.0, preset("fast", iterations=20, batch=256, max_resolution=8))[0]
    assert capped.grid_kind == "capped" and capped.grid == (8, 8)  # the cap (8) is below the density's 16
    assert "max 8 per side" in capped.warnings[0] and "the cap decides" in capped.notes[0]
    density = plan(asset, 8.0, preset("fast", iterations=20, batch=256, max_resolution=32))[0]
    assert density.grid_kind == "density" and density.grid == (16, 16)  # the density (16) is below the cap


def test_equal_materials_on_meshes_of_different_density_train_apart(tmp_path):
    asset = textured_scene(tmp_path, {"A": 2.0, "B": 0.5})
    a, b = plan(asset, None)
    assert b.shared_with == "/World/Looks/A"  # equal content: trained once
    a, b = plan(asset, 8.0)  # A: 16 texels per UV unit, B: 0.5 m x 8 = 4
    assert (a.grid, b.grid) == ((16, 16), (4, 4)) and b.shared_with is None and a.content != b.content


def test_uniform_material_stays_one_texel(tmp_path):
    asset = textured_scene(tmp_path, {"A": 2.0}, uniform=True)
    p = plan(asset, 8.0)[0]
    assert p.grid_kind == "uniform" and p.grid == (1, 1) and p.warnings == [] and p.surface is None


def test_mtlx_input_or_no_uvs_make_the_density_a_note(tmp_path):
    from pxr import Usd, UsdGeom

    asset = textured_scene(tmp_path, {"A": 2.0})
    mtlx = tmp_path / "tex.mtlx"
    import MaterialX as mx

    mtlx.write_text(mx.writeToXmlString(load_asset(asset).materials[0].document))
    p = plan(mtlx, 8.0)[0]
    assert p.grid_kind == "native" and p.grid == (64, 64) and p.warnings == []
    assert "--texel-density has no effect" in p.notes[0] and "MaterialX file" in p.notes[0]
    stage = Usd.Stage.Open(str(asset))
    UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Geo_A")).RemovePrimvar("st")
    stage.GetRootLayer().Save()
    p = plan(asset, 8.0)[0]
    assert p.grid_kind == "native" and "no st primvar" in p.notes[0]


# ----------------------------------------------------------------------------- command line


def test_cli_inspect_texel_density(tmp_path, capsys):
    asset = textured_scene(tmp_path, {"A": 2.0})
    assert main(["inspect", str(asset), "--texel-density", "8", "--json"]) == 0
    latent = json.loads(capsys.readouterr().out)["materials"][0]["latent"]
    assert latent["kind"] == "density" and latent["grid"] == [16, 16] and latent["density_texels"] == 16
    assert latent["metres_per_uv"] == pytest.approx(2.0, rel=REL) and latent["texel_density"] == 8.0
    assert latent["density_meshes"][0]["prim"] == "/World/Geo_A"
    assert main(["inspect", str(asset), "--texel-density", "8"]) == 0
    text = capsys.readouterr().out
    assert "latent grid: 16x16, from the scene's texel density (8 texels/m; textures 64x64" in text
    assert ("texel density: 2 m of surface per UV unit (metersPerUnit 1) x 8 texels/m = 16 texels per UV unit: "
            "density grid") in text
    assert "warning: /World/Looks/A: latent grid 16x16" in text
    for bad in ("0", "-5", "abc", "inf"):
        with pytest.raises(SystemExit) as e:
            main(["inspect", str(asset), "--texel-density", bad])
        assert e.value.code == 2
    assert "is not a texel density" in capsys.readouterr().err


@pytest.mark.slow
def test_convert_trains_the_planned_grid(tmp_path, capsys):
    asset = textured_scene(tmp_path, {"A": 2.0})
    args = [str(asset), "--texel-density", "8", "--quiet", "--iterations", "20", "--batch", "256", "--device", "cpu",
            "--workers", "1"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "warning: /World/Looks/A: latent grid 16x16 from the scene's texel density" in out
    summary = json.loads((tmp_path / "scene_neural" / "World.Looks.A" / "summary.json").read_text())
    p = plan(asset, 8.0, preset("fast", iterations=20, batch=256))[0]
    assert summary["resolution"] == [16, 16] and summary["source_hash"] == p.digest
    assert summary["latent"]["kind"] == "density" and summary["config"]["max_resolution"] == 16
