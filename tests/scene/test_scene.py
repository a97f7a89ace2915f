"""Tests for the scene stage: .mtlx files, USD stages, binding selection, bad input."""

from __future__ import annotations

import functools
import os
import struct
import zlib
from pathlib import Path

import MaterialX as mx
import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

from mtlx2neural.errors import InputError
from mtlx2neural.scene import (
    MaterialSource,
    SceneMaterials,
    find_material,
    load_asset,
    mxlib,
)

SHARED = Path(__file__).resolve().parents[2].parent / "shared"
ASSETS = SHARED / "assets"
MTLX_EXAMPLES = ASSETS / "materialx" / "resources" / "Materials" / "Examples"
MTLX_TEST = ASSETS / "usd" / "test_assets" / "MaterialXTest"

needs_shared = pytest.mark.skipif(
    not (MTLX_EXAMPLES.is_dir() and MTLX_TEST.is_dir()),
    reason=f"shared test assets not found under {ASSETS}",
)

RNG_SEED = 1234


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------
def write_png(path: Path, rgb=(128, 64, 32)) -> Path:
    """Write a real 1x1 8-bit RGB PNG."""

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    raw = b"\x00" + bytes(rgb)
    png = (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", 1, 1, 8, 2, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(raw))
        + chunk(b"IEND", b"")
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(png)
    return path


@functools.lru_cache(maxsize=1)
def _libraries() -> "mx.Document":
    lib = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), lib)
    return lib


def validate_with_libraries(doc: "mx.Document") -> None:
    """Independent check: import the libraries into a scratch copy and validate it."""
    scratch = mx.createDocument()
    scratch.copyContentFrom(doc)
    scratch.importLibrary(_libraries())
    ok, msg = scratch.validate()
    assert ok, msg
    for node in doc.traverseTree():
        if isinstance(node, mx.Node):
            assert scratch.getDescendant(node.getNamePath()).getNodeDef() is not None, node.getNamePath()


def filename_inputs(doc: "mx.Document") -> list["mx.Input"]:
    return [e for e in doc.traverseTree() if isinstance(e, mx.Input) and e.getType() == "filename"]


def surface_node(src: MaterialSource) -> "mx.Node":
    mat = src.document.getNode(src.material)
    assert mat is not None and mat.getCategory() == "surfacematerial"
    return mat.getInput("surfaceshader").getConnectedNode()


def add_mesh(stage: Usd.Stage, path: str) -> UsdGeom.Mesh:
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    return mesh


def mtlx_material(
    stage: Usd.Stage, path: str, color, texture: str | None = None, tiling=(3.0, 3.0)
) -> UsdShade.Material:
    """A standard_surface MaterialX network; with ``texture``, base_color comes from a
    tiledimage inside a NodeGraph whose interface input drives the tiling."""
    mat = UsdShade.Material.Define(stage, path)
    rough = mat.CreateInput("rough", Sdf.ValueTypeNames.Float)
    rough.Set(0.25)
    sr = UsdShade.Shader.Define(stage, f"{path}/SR_surface")
    sr.CreateIdAttr("ND_standard_surface_surfaceshader")
    sr.CreateInput("base", Sdf.ValueTypeNames.Float).Set(0.8)
    sr.CreateInput("metalness", Sdf.ValueTypeNames.Float).Set(1.0)
    sr.CreateInput("specular_roughness", Sdf.ValueTypeNames.Float).ConnectToSource(rough)
    base_color = sr.CreateInput("base_color", Sdf.ValueTypeNames.Color3f)
    if texture is None:
        base_color.Set(Gf.Vec3f(*color))
    else:
        ng = UsdShade.NodeGraph.Define(stage, f"{path}/NG_tex")
        tiling_in = ng.CreateInput("tiling", Sdf.ValueTypeNames.Float2)
        tiling_in.Set(Gf.Vec2f(*tiling))
        img = UsdShade.Shader.Define(stage, f"{path}/NG_tex/image_color")
        img.CreateIdAttr("ND_tiledimage_color3")
        file_in = img.CreateInput("file", Sdf.ValueTypeNames.Asset)
        file_in.Set(Sdf.AssetPath(texture))
        file_in.GetAttr().SetColorSpace("srgb_texture")
        img.CreateInput("uvtiling", Sdf.ValueTypeNames.Float2).ConnectToSource(tiling_in)
        img_out = img.CreateOutput("out", Sdf.ValueTypeNames.Color3f)
        ng_out = ng.CreateOutput("out_color", Sdf.ValueTypeNames.Color3f)
        ng_out.ConnectToSource(img_out)
        base_color.ConnectToSource(ng_out)
    surf = sr.CreateOutput("surface", Sdf.ValueTypeNames.Token)
    mat.CreateSurfaceOutput("mtlx").ConnectToSource(surf)
    return mat


def bind(prim: Usd.Prim, mat: UsdShade.Material) -> None:
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(mat)


def listing(directory: Path) -> set[str]:
    return {str(p.relative_to(directory)) for p in directory.rglob("*")}


# ---------------------------------------------------------------------------
# .mtlx input
# ---------------------------------------------------------------------------
@needs_shared
def test_mtlx_wood_tiled_filenames_absolute_and_existing():
    path = MTLX_EXAMPLES / "StandardSurface" / "standard_surface_wood_tiled.mtlx"
    scene = load_asset(path)
    assert isinstance(scene, SceneMaterials)
    assert scene.asset == str(path)
    assert [m.name for m in scene.materials] == ["Tiled_Wood"]
    assert scene.skipped == []
    src = scene.materials[0]
    assert src.material == "Tiled_Wood" and src.bound_prims == []
    assert src.source_file == str(path)
    files = filename_inputs(src.document)
    assert len(files) == 2
    for inp in files:
        value = inp.getValueString()
        assert os.path.isabs(value) and os.path.isfile(value), value
        assert inp.getResolvedValueString() == value  # no fileprefix left to re-apply
    assert {os.path.basename(i.getValueString()) for i in files} == {"wood_color.jpg", "wood_roughness.jpg"}
    # only user content: no library nodedefs/implementations copied in
    assert src.document.getNodeDefs() == []
    assert src.document.getImplementations() == []
    assert surface_node(src).getCategory() == "standard_surface"
    validate_with_libraries(src.document)
    # find_material: the only material, by default and by name
    assert find_material(path).material == "Tiled_Wood"
    assert find_material(path, "Tiled_Wood").name == "Tiled_Wood"


@needs_shared
def test_mtlx_xinclude_look_file_every_material_selected():
    path = MTLX_EXAMPLES / "StandardSurface" / "standard_surface_look_wood_tiled.mtlx"
    scene = load_asset(path)
    assert [m.name for m in scene.materials] == ["Tiled_Wood", "Greysphere_Calibration"]
    for src in scene.materials:
        for inp in filename_inputs(src.document):
            assert os.path.isabs(inp.getValueString())
        # self-contained: writes out without xi:include
        assert "xi:include" not in mx.writeToXmlString(src.document)
    # documents are independent copies
    scene.materials[0].document.removeNode("Tiled_Wood")
    assert scene.materials[1].document.getNode("Tiled_Wood") is not None
    with pytest.raises(InputError) as err:
        find_material(path)
    assert "Tiled_Wood" in str(err.value) and "Greysphere_Calibration" in str(err.value)
    assert str(path) in str(err.value)


@needs_shared
@pytest.mark.parametrize(
    "path",
    sorted(MTLX_EXAMPLES.rglob("*.mtlx")) if MTLX_EXAMPLES.is_dir() else [],
    ids=lambda p: p.name,
)
def test_mtlx_examples_load(path):
    scene = load_asset(path)
    assert scene.materials, path
    for src in scene.materials:
        assert src.document.getNode(src.material).getCategory() == "surfacematerial"
        for inp in filename_inputs(src.document):
            assert os.path.isabs(inp.getValueString()), inp.getValueString()


def test_mtlx_udim_token_kept_and_prefix_applied(tmp_path):
    (tmp_path / "sub").mkdir()
    path = tmp_path / "sub" / "udim.mtlx"
    path.write_text(
        """<?xml version="1.0"?>
<materialx version="1.39">
  <nodegraph name="NG" fileprefix="../tex/">
    <image name="img" type="color3">
      <input name="file" type="filename" value="color.&lt;UDIM&gt;.png" colorspace="srgb_texture" />
    </image>
    <output name="out" type="color3" nodename="img" />
  </nodegraph>
  <standard_surface name="SR" type="surfaceshader">
    <input name="base_color" type="color3" nodegraph="NG" output="out" />
  </standard_surface>
  <surfacematerial name="M" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="SR" />
  </surfacematerial>
</materialx>
"""
    )
    src = find_material(path)
    (inp,) = filename_inputs(src.document)
    assert inp.getValueString() == str(tmp_path / "tex" / "color.<UDIM>.png")


# ---------------------------------------------------------------------------
# USD: binding selection
# ---------------------------------------------------------------------------
@pytest.fixture
def bound_stage(tmp_path):
    """A stage whose Materials live in a referenced layer in a sub-folder and are bound
    directly, via a collection, by inheritance, only to an invisible mesh, only to a
    guide mesh, through a GeomSubset, or not at all."""
    rng = np.random.default_rng(RNG_SEED)
    colors = {
        name: tuple(float(c) for c in rng.uniform(0.05, 0.95, 3))
        for name in ["Brass", "Hidden", "ViaCollection", "Inherited", "GuideOnly", "Unbound", "SubsetMat"]
    }
    write_png(tmp_path / "textures" / "brass.png")

    looks = Usd.Stage.CreateNew(str(tmp_path / "looks" / "looks.usda"))
    UsdGeom.Scope.Define(looks, "/Looks")
    looks.SetDefaultPrim(looks.GetPrimAtPath("/Looks"))
    for name, color in colors.items():
        texture = "../textures/brass.png" if name == "Brass" else None
        mtlx_material(looks, f"/Looks/{name}", color, texture=texture)
    looks.GetRootLayer().Save()

    root_path = tmp_path / "scene.usda"
    stage = Usd.Stage.CreateNew(str(root_path))
    world = UsdGeom.Xform.Define(stage, "/World").GetPrim()
    stage.SetDefaultPrim(world)
    looks_prim = stage.DefinePrim("/World/Looks")
    looks_prim.GetReferences().AddReference("./looks/looks.usda")
    mat = {name: UsdShade.Material(stage.GetPrimAtPath(f"/World/Looks/{name}")) for name in colors}
    assert all(m for m in mat.values())

    visible = add_mesh(stage, "/World/Geo/Visible")
    bind(visible.GetPrim(), mat["Brass"])
    hidden = add_mesh(stage, "/World/Geo/Hidden")
    hidden.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    bind(hidden.GetPrim(), mat["Hidden"])
    # invisible through an invisible parent, bound to Brass as well: must not matter
    hidden_parent = UsdGeom.Xform.Define(stage, "/World/Geo/HiddenGroup")
    hidden_parent.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    bind(add_mesh(stage, "/World/Geo/HiddenGroup/Child").GetPrim(), mat["Hidden"])
    # collection binding on /World
    add_mesh(stage, "/World/Geo/CollectionTarget")
    coll = Usd.CollectionAPI.Apply(world, "shiny")
    coll.CreateIncludesRel().AddTarget("/World/Geo/CollectionTarget")
    UsdShade.MaterialBindingAPI.Apply(world).Bind(coll, mat["ViaCollection"], bindingName="shiny")
    # inherited from a parent Xform
    parent = UsdGeom.Xform.Define(stage, "/World/Geo/Parent")
    bind(parent.GetPrim(), mat["Inherited"])
    add_mesh(stage, "/World/Geo/Parent/Child")
    # guide-purpose mesh
    guide = add_mesh(stage, "/World/Geo/Guide")
    guide.CreatePurposeAttr(UsdGeom.Tokens.guide)
    bind(guide.GetPrim(), mat["GuideOnly"])
    # per-face binding through a GeomSubset of a visible mesh
    split = add_mesh(stage, "/World/Geo/Split")
    bind(split.GetPrim(), mat["Brass"])
    subset = UsdShade.MaterialBindingAPI(split.GetPrim()).CreateMaterialBindSubset("faces", [0])
    bind(subset.GetPrim(), mat["SubsetMat"])
    stage.GetRootLayer().Save()
    return root_path, colors


def test_binding_selection(bound_stage, tmp_path):
    path, _ = bound_stage
    before = listing(tmp_path)
    scene = load_asset(path)
    assert listing(tmp_path) == before  # nothing written next to the input
    selected = {m.name: m for m in scene.materials}
    assert set(selected) == {
        "/World/Looks/Brass",
        "/World/Looks/ViaCollection",
        "/World/Looks/Inherited",
        "/World/Looks/SubsetMat",
    }
    assert selected["/World/Looks/Brass"].bound_prims == ["/World/Geo/Visible", "/World/Geo/Split"]
    assert selected["/World/Looks/ViaCollection"].bound_prims == ["/World/Geo/CollectionTarget"]
    assert selected["/World/Looks/Inherited"].bound_prims == ["/World/Geo/Parent/Child"]
    assert selected["/World/Looks/SubsetMat"].bound_prims == ["/World/Geo/Split/faces"]
    skipped = dict(scene.skipped)
    assert set(skipped) == {"/World/Looks/Hidden", "/World/Looks/GuideOnly", "/World/Looks/Unbound"}
    assert skipped["/World/Looks/Hidden"].startswith("bound only to invisible prims")
    assert "/World/Geo/HiddenGroup/Child" in skipped["/World/Looks/Hidden"]
    assert skipped["/World/Looks/GuideOnly"].startswith("bound only to proxy/guide prims")
    assert skipped["/World/Looks/Unbound"] == "not bound to any renderable prim"
    for src in scene.materials:
        assert src.source_file == str(tmp_path / "looks" / "looks.usda")
        validate_with_libraries(src.document)


def test_converted_network_nodegraph_values_and_paths(bound_stage, tmp_path):
    path, colors = bound_stage
    src = find_material(path, "/World/Looks/Brass")
    assert src.name == "/World/Looks/Brass" and src.material == "Brass"
    doc = src.document
    assert doc.getNodeDefs() == []
    sr = surface_node(src)
    assert sr.getCategory() == "standard_surface" and sr.getNodeDefString() == "ND_standard_surface_surfaceshader"
    assert sr.getInput("base").getValue() == pytest.approx(0.8)
    # Material interface input resolved to its value
    assert sr.getInput("specular_roughness").getValue() == pytest.approx(0.25)
    # NodeGraph flattened: base_color connects straight to the tiledimage node
    img = sr.getInput("base_color").getConnectedNode()
    assert img.getCategory() == "tiledimage" and img.getType() == "color3"
    assert img.getDocString() == "/World/Looks/Brass/NG_tex/image_color"
    file_in = img.getInput("file")
    assert file_in.getValueString() == str(tmp_path / "textures" / "brass.png")  # relative to looks/looks.usda
    assert file_in.getColorSpace() == "srgb_texture"
    # NodeGraph interface input resolved to its value
    assert list(img.getInput("uvtiling").getValue()) == pytest.approx([3.0, 3.0])
    validate_with_libraries(doc)

    # untextured material: seeded colour round-trips at float32 precision
    plain = find_material(path, "Unbound")  # explicit name: returned although unbound
    assert plain.name == "/World/Looks/Unbound" and plain.bound_prims == []
    got = list(surface_node(plain).getInput("base_color").getValue())
    assert got == pytest.approx(colors["Unbound"], abs=1e-6)


def test_find_material_selection_errors(bound_stage):
    path, _ = bound_stage
    with pytest.raises(InputError) as err:
        find_material(path)  # four selected materials
    msg = str(err.value)
    assert str(path) in msg and "/World/Looks/Brass" in msg and "/World/Looks/Inherited" in msg
    with pytest.raises(InputError) as err:
        find_material(path, "NoSuchMaterial")
    msg = str(err.value)
    assert "NoSuchMaterial" in msg and str(path) in msg and "/World/Looks/Unbound" in msg


def test_stage_without_geometry_skips_all_but_explicit_name_works(tmp_path):
    path = tmp_path / "library.usda"
    stage = Usd.Stage.CreateNew(str(path))
    mtlx_material(stage, "/Lib/A", (0.2, 0.3, 0.4))
    mtlx_material(stage, "/Lib/B", (0.5, 0.5, 0.5))
    stage.GetRootLayer().Save()
    scene = load_asset(path)
    assert scene.materials == []
    assert scene.skipped == [
        ("/Lib/A", "stage has no renderable geometry"),
        ("/Lib/B", "stage has no renderable geometry"),
    ]
    with pytest.raises(InputError) as err:
        find_material(path)
    assert "stage has no renderable geometry" in str(err.value) and str(path) in str(err.value)
    src = find_material(path, "B")
    assert src.name == "/Lib/B" and src.bound_prims == []


def test_broken_unbound_material_does_not_block_load(tmp_path):
    path = tmp_path / "scene.usda"
    stage = Usd.Stage.CreateNew(str(path))
    good = mtlx_material(stage, "/Looks/Good", (0.5, 0.5, 0.5))
    broken = UsdShade.Material.Define(stage, "/Looks/Broken")  # no surface terminal
    bind(add_mesh(stage, "/Geo/Mesh").GetPrim(), good)
    stage.GetRootLayer().Save()
    scene = load_asset(path)
    assert [m.name for m in scene.materials] == ["/Looks/Good"]
    assert dict(scene.skipped) == {"/Looks/Broken": "not bound to any renderable prim"}
    assert find_material(path).name == "/Looks/Good"
    with pytest.raises(InputError) as err:
        find_material(path, "Broken")
    assert "/Looks/Broken" in str(err.value) and str(path) in str(err.value)
    assert "surface" in str(err.value)
    del broken


# ---------------------------------------------------------------------------
# USD: real MaterialXTest files
# ---------------------------------------------------------------------------
@needs_shared
@pytest.mark.parametrize(
    "file, material, category",
    [
        ("basicTextured_flatten.usda", "Tiled_Brass", "standard_surface"),
        ("basicTextured_flatten.usda", "/MaterialX/Materials/USD_Plastic", "UsdPreviewSurface"),
        ("basic_flatten.usda", "USD_Plastic", "UsdPreviewSurface"),
    ],
)
def test_materialxtest_flattened(file, material, category):
    path = MTLX_TEST / file
    src = find_material(path, material)
    assert src.name.startswith("/MaterialX/Materials/")
    assert src.source_file == str(path)
    node = surface_node(src)
    assert node.getCategory() == category
    validate_with_libraries(src.document)
    if category == "standard_surface":
        images = [n for n in src.document.getNodes() if n.getCategory() == "tiledimage"]
        assert {n.getNodeDefString() for n in images} == {"ND_tiledimage_color3", "ND_tiledimage_float"}
        for n in images:
            value = n.getInputValue("file")
            assert os.path.isabs(value) and value.startswith(str(MTLX_TEST / "textures")), value
        roughness = node.getInput("coat_roughness").getConnectedNode()
        assert roughness.getNodeDefString() == "ND_tiledimage_float"
        assert node.getInput("metalness").getValue() == pytest.approx(1.0)
    else:
        assert list(node.getInput("diffuseColor").getValue()) == pytest.approx(
            [0.10470402, 0.24188282, 0.818], abs=1e-6
        )


@needs_shared
def test_materialxtest_flattened_selection():
    scene = load_asset(MTLX_TEST / "basicTextured_flatten.usda")
    assert [(m.name, m.bound_prims) for m in scene.materials] == [
        ("/MaterialX/Materials/Tiled_Brass", ["/Teapot/teapot_MeshShape"])
    ]
    assert scene.skipped == [("/MaterialX/Materials/USD_Plastic", "not bound to any renderable prim")]


@needs_shared
def test_basic_usda_reads_referenced_mtlx():
    path = MTLX_TEST / "basic.usda"
    src = find_material(path)
    assert src.name == "/MaterialX/Materials/USD_Plastic"
    assert src.material == "USD_Plastic"
    assert src.source_file == str(MTLX_TEST / "usd_preview_surface_plastic.mtlx")
    assert src.bound_prims == ["/sphere"]
    node = surface_node(src)
    assert node.getCategory() == "UsdPreviewSurface" and node.getName() == "SR_plastic"
    validate_with_libraries(src.document)


@needs_shared
def test_basic_textured_usda_variant_binding_and_mtlx_reference():
    path = MTLX_TEST / "basicTextured.usda"
    scene = load_asset(path)
    assert [m.name for m in scene.materials] == ["/MaterialX/Materials/Tiled_Brass"]
    src = scene.materials[0]
    assert src.source_file == str(MTLX_TEST / "standard_surface_brass_tiled.mtlx")
    assert src.bound_prims == ["/Teapot/teapot_MeshShape"]
    assert dict(scene.skipped) == {"/MaterialX/Materials/USD_Plastic": "not bound to any renderable prim"}
    # this file repeats its fileprefix in the values (written for usdMtlx); the existing file is kept
    values = {os.path.basename(i.getValueString()): i.getValueString() for i in filename_inputs(src.document)}
    assert values["brass_roughness.jpg"] == str(MTLX_TEST / "textures" / "brass_roughness.jpg")
    plastic = find_material(path, "USD_Plastic")
    assert plastic.source_file == str(MTLX_TEST / "usd_preview_surface_plastic.mtlx")


def test_mtlx_reference_with_prim_path_on_material_prim(tmp_path):
    mtlx = tmp_path / "lib" / "two.mtlx"
    mtlx.parent.mkdir()
    write_png(tmp_path / "lib" / "tex" / "c.png")
    mtlx.write_text(
        """<?xml version="1.0"?>
<materialx version="1.39">
  <image name="img" type="color3"><input name="file" type="filename" value="tex/c.png" /></image>
  <standard_surface name="SR_a" type="surfaceshader"><input name="base_color" type="color3" nodename="img" /></standard_surface>
  <surfacematerial name="A" type="material"><input name="surfaceshader" type="surfaceshader" nodename="SR_a" /></surfacematerial>
  <standard_surface name="SR_b" type="surfaceshader" />
  <surfacematerial name="B" type="material"><input name="surfaceshader" type="surfaceshader" nodename="SR_b" /></surfacematerial>
</materialx>
"""
    )
    path = tmp_path / "scene.usda"
    stage = Usd.Stage.CreateNew(str(path))
    look = stage.DefinePrim("/World/Looks/Wood", "Material")
    look.GetReferences().AddReference("./lib/two.mtlx", "/MaterialX/Materials/A")
    mesh = add_mesh(stage, "/World/Mesh")
    rel = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).GetDirectBindingRel()
    rel.AddTarget("/World/Looks/Wood")
    stage.GetRootLayer().Save()
    scene = load_asset(path)
    assert [(m.name, m.material, m.bound_prims) for m in scene.materials] == [
        ("/World/Looks/Wood", "A", ["/World/Mesh"])
    ]
    (src,) = scene.materials
    assert src.source_file == str(mtlx)
    assert filename_inputs(src.document)[0].getValueString() == str(tmp_path / "lib" / "tex" / "c.png")
    assert find_material(path, "A").name == "/World/Looks/Wood"  # the .mtlx name works too


# ---------------------------------------------------------------------------
# USD: UsdPreviewSurface networks
# ---------------------------------------------------------------------------
def preview_material(stage: Usd.Stage, path: str, tex_dir: str) -> UsdShade.Material:
    mat = UsdShade.Material.Define(stage, path)
    st_name = mat.CreateInput("frame:stPrimvarName", Sdf.ValueTypeNames.Token)
    st_name.Set("st")
    pbr = UsdShade.Shader.Define(stage, f"{path}/PBR")
    pbr.CreateIdAttr("UsdPreviewSurface")
    pbr.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.4)
    pbr.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    reader = UsdShade.Shader.Define(stage, f"{path}/stReader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).ConnectToSource(st_name)
    reader_out = reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    xform = UsdShade.Shader.Define(stage, f"{path}/Transform")
    xform.CreateIdAttr("UsdTransform2d")
    xform.CreateInput("in", Sdf.ValueTypeNames.Float2).ConnectToSource(reader_out)
    xform.CreateInput("scale", Sdf.ValueTypeNames.Float2).Set(Gf.Vec2f(2, 3))
    xform.CreateInput("rotation", Sdf.ValueTypeNames.Float).Set(30.0)
    xform_out = xform.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    diffuse = UsdShade.Shader.Define(stage, f"{path}/DiffuseTex")
    diffuse.CreateIdAttr("UsdUVTexture")
    diffuse.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(f"{tex_dir}/diffuse.png")
    diffuse.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(xform_out)
    diffuse.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
    diffuse.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("mirror")
    diffuse.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    diffuse.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(0.5, 0.5, 0.5, 1))
    rgb = diffuse.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(rgb)
    normal_tex = UsdShade.Shader.Define(stage, f"{path}/NormalTex")
    normal_tex.CreateIdAttr("UsdUVTexture")
    normal_tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(f"{tex_dir}/normal.png")
    normal_tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
    normal_tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader_out)
    n_rgb = normal_tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    pbr.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(n_rgb)
    mat.CreateSurfaceOutput().ConnectToSource(pbr.CreateOutput("surface", Sdf.ValueTypeNames.Token))
    return mat


def test_usd_preview_surface_network(tmp_path):
    write_png(tmp_path / "maps" / "diffuse.png")
    write_png(tmp_path / "maps" / "normal.png", (128, 128, 255))
    path = tmp_path / "preview.usda"
    stage = Usd.Stage.CreateNew(str(path))
    mat = preview_material(stage, "/World/Looks/Painted", "./maps")
    bind(add_mesh(stage, "/World/Mesh").GetPrim(), mat)
    stage.GetRootLayer().Save()

    src = find_material(path)
    assert src.name == "/World/Looks/Painted" and src.bound_prims == ["/World/Mesh"]
    doc = src.document
    pbr = surface_node(src)
    assert pbr.getNodeDefString() == "ND_UsdPreviewSurface_surfaceshader"
    assert pbr.getInput("roughness").getValue() == pytest.approx(0.4)
    tex = pbr.getInput("diffuseColor").getConnectedNode()
    assert tex.getNodeDefString() == "ND_UsdUVTexture_23" and tex.getType() == "multioutput"
    assert pbr.getInput("diffuseColor").getOutputString() == "rgb"
    assert tex.getInput("file").getValueString() == str(tmp_path / "maps" / "diffuse.png")
    assert tex.getInput("file").getColorSpace() == "srgb_texture"
    assert tex.getInputValue("wrapS") == "periodic" and tex.getInputValue("wrapT") == "mirror"
    assert list(tex.getInputValue("scale")) == pytest.approx([0.5, 0.5, 0.5, 1.0])
    assert tex.getInput("sourceColorSpace") is None
    xform = tex.getInput("st").getConnectedNode()
    assert xform.getNodeDefString() == "ND_UsdTransform2d"
    assert list(xform.getInputValue("scale")) == pytest.approx([2.0, 3.0])
    assert xform.getInputValue("rotation") == pytest.approx(30.0)
    reader = xform.getInput("in").getConnectedNode()
    assert reader.getNodeDefString() == "ND_UsdPrimvarReader_vector2"
    assert reader.getInputValue("varname") == "st"
    # color3 texture output into the vector3 normal input goes through a convert node
    conv = pbr.getInput("normal").getConnectedNode()
    assert conv.getCategory() == "convert" and conv.getNodeDefString() == "ND_convert_color3_vector3"
    ntex = conv.getInput("in").getConnectedNode()
    assert conv.getInput("in").getOutputString() == "rgb"
    assert ntex.getInput("file").getValueString() == str(tmp_path / "maps" / "normal.png")
    assert not ntex.getInput("file").hasColorSpace()  # raw: no colour transform
    assert len([n for n in doc.getNodes() if n.getCategory() == "UsdUVTexture"]) == 2
    validate_with_libraries(doc)


def test_mtlx_context_preferred_over_universal(tmp_path):
    path = tmp_path / "both.usda"
    stage = Usd.Stage.CreateNew(str(path))
    mat = mtlx_material(stage, "/Looks/Both", (0.1, 0.2, 0.3))
    pbr = UsdShade.Shader.Define(stage, "/Looks/Both/Preview")
    pbr.CreateIdAttr("UsdPreviewSurface")
    mat.CreateSurfaceOutput().ConnectToSource(pbr.CreateOutput("surface", Sdf.ValueTypeNames.Token))
    bind(add_mesh(stage, "/Mesh").GetPrim(), mat)
    stage.GetRootLayer().Save()
    src = find_material(path)
    assert surface_node(src).getCategory() == "standard_surface"
    assert src.document.getNode("Preview") is None  # the universal network is not converted


# ---------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------
def _stage_with(tmp_path, build) -> Path:
    path = tmp_path / "bad.usda"
    stage = Usd.Stage.CreateNew(str(path))
    mat = build(stage)
    bind(add_mesh(stage, "/Geo/Mesh").GetPrim(), mat)
    stage.GetRootLayer().Save()
    return path


def _unknown_id(stage):
    mat = mtlx_material(stage, "/Looks/Weird", (0.5, 0.5, 0.5))
    UsdShade.Shader(stage.GetPrimAtPath("/Looks/Weird/SR_surface")).SetShaderId("ND_not_a_real_node_color3")
    return mat


def _no_terminal(stage):
    mat = UsdShade.Material.Define(stage, "/Looks/Empty")
    shader = UsdShade.Shader.Define(stage, "/Looks/Empty/SR")
    shader.CreateIdAttr("ND_standard_surface_surfaceshader")
    return mat


def _unknown_input(stage):
    mat = mtlx_material(stage, "/Looks/Extra", (0.5, 0.5, 0.5))
    sr = UsdShade.Shader(stage.GetPrimAtPath("/Looks/Extra/SR_surface"))
    sr.CreateInput("shininess", Sdf.ValueTypeNames.Float).Set(3.0)
    return mat


def _wrong_value_type(stage):
    mat = mtlx_material(stage, "/Looks/Typed", (0.5, 0.5, 0.5))
    sr = UsdShade.Shader(stage.GetPrimAtPath("/Looks/Typed/SR_surface"))
    sr.GetPrim().RemoveProperty("inputs:base")
    sr.CreateInput("base", Sdf.ValueTypeNames.Float3).Set(Gf.Vec3f(1, 2, 3))
    return mat


def _no_id(stage):
    mat = mtlx_material(stage, "/Looks/NoId", (0.5, 0.5, 0.5))
    stage.GetPrimAtPath("/Looks/NoId/SR_surface").RemoveProperty("info:id")
    return mat


@pytest.mark.parametrize(
    "build, needles",
    [
        (_unknown_id, ["/Looks/Weird/SR_surface", "ND_not_a_real_node_color3"]),
        (_no_terminal, ["/Looks/Empty", "surface"]),
        (_unknown_input, ["/Looks/Extra/SR_surface", "shininess", "ND_standard_surface_surfaceshader"]),
        (_wrong_value_type, ["/Looks/Typed/SR_surface", "base", "float"]),
        (_no_id, ["/Looks/NoId/SR_surface", "info:id"]),
    ],
    ids=["unknown-id", "no-terminal", "unknown-input", "wrong-value-type", "no-id"],
)
def test_bad_usd_networks(tmp_path, build, needles):
    path = _stage_with(tmp_path, build)
    with pytest.raises(InputError) as err:
        load_asset(path)
    msg = str(err.value)
    assert str(path) in msg, msg
    for needle in needles:
        assert needle in msg, (needle, msg)
    assert err.value.exit_code == 2


@pytest.mark.parametrize("name", ["missing.usda", "missing.mtlx", "missing.usdc"])
def test_missing_file(tmp_path, name):
    path = tmp_path / name
    for call in (load_asset, find_material):
        with pytest.raises(InputError) as err:
            call(path)
        assert str(path) in str(err.value) and "not found" in str(err.value)


def test_unknown_extension(tmp_path):
    path = tmp_path / "teapot.obj"
    path.write_text("v 0 0 0\n")
    with pytest.raises(InputError) as err:
        load_asset(path)
    assert str(path) in str(err.value) and ".obj" in str(err.value)


def test_malformed_xml(tmp_path):
    path = tmp_path / "broken.mtlx"
    path.write_text(
        '<?xml version="1.0"?>\n<materialx version="1.39">\n  <standard_surface name="x" type="surfaceshader">\n</materialx>\n'
    )
    with pytest.raises(InputError) as err:
        load_asset(path)
    assert str(path) in str(err.value)


def test_invalid_materialx_document(tmp_path):
    path = tmp_path / "invalid.mtlx"
    path.write_text(
        """<?xml version="1.0"?>
<materialx version="1.39">
  <no_such_node name="n1" type="surfaceshader" />
  <surfacematerial name="M" type="material"><input name="surfaceshader" type="surfaceshader" nodename="n1" /></surfacematerial>
</materialx>
"""
    )
    with pytest.raises(InputError) as err:
        find_material(path, "M")
    assert str(path) in str(err.value) and "n1" in str(err.value)


def test_missing_xinclude(tmp_path):
    path = tmp_path / "incl.mtlx"
    path.write_text(
        '<?xml version="1.0"?>\n<materialx version="1.39" xmlns:xi="http://www.w3.org/2001/XInclude">\n'
        '  <xi:include href="nowhere.mtlx" />\n</materialx>\n'
    )
    with pytest.raises(InputError) as err:
        load_asset(path)
    assert str(path) in str(err.value)


def test_malformed_usda(tmp_path):
    path = tmp_path / "broken.usda"
    path.write_text('#usda 1.0\ndef Xform "World" {\n    float x = \n}\n')
    with pytest.raises(InputError) as err:
        load_asset(path)
    assert str(path) in str(err.value)


def test_unknown_material_name_lists_choices(tmp_path):
    path = tmp_path / "one.mtlx"
    path.write_text(
        """<?xml version="1.0"?>
<materialx version="1.39">
  <standard_surface name="SR" type="surfaceshader" />
  <surfacematerial name="Only" type="material"><input name="surfaceshader" type="surfaceshader" nodename="SR" /></surfacematerial>
</materialx>
"""
    )
    with pytest.raises(InputError) as err:
        find_material(path, "Other")
    msg = str(err.value)
    assert str(path) in msg and "Other" in msg and "Only" in msg


def test_missing_referenced_mtlx(tmp_path):
    path = tmp_path / "ref.usda"
    stage = Usd.Stage.CreateNew(str(path))
    stage.DefinePrim("/MaterialX", "Scope").GetReferences().AddReference("./gone.mtlx", "/MaterialX")
    stage.GetRootLayer().Save()
    with pytest.raises(InputError) as err:
        load_asset(path)
    assert str(tmp_path / "gone.mtlx") in str(err.value)


def test_scratch_validation_does_not_touch_document():
    doc = mx.createDocument()
    node = doc.addNode("standard_surface", "SR", "surfaceshader")
    mat = doc.addNode("surfacematerial", "M", "material")
    mat.addInput("surfaceshader", "surfaceshader").setNodeName(node.getName())
    mxlib.validate(doc, "in-memory")
    assert doc.getNodeDefs() == [] and len(doc.getChildren()) == 2
