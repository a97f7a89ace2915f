"""Geometry-driven inputs: graphs that read position, normal or primvars bake from the bound meshes
(mtlx2neural.graph.geometry, the evaluator, the parameter stack and the reference)."""

from __future__ import annotations

import math

import MaterialX as mx
import numpy as np
import pytest
import torch
from conftest import write_float_image
from materials import document, standard_surface

pytest.importorskip("pxr", reason="usd-core is needed to build the test stages")

from mtlx2neural.errors import InputError  # noqa: E402
from mtlx2neural.graph import compile_material  # noqa: E402
from mtlx2neural.graph.geometry import bind_geometry, geometry_reads  # noqa: E402
from mtlx2neural.graph.ir import Ref  # noqa: E402
from mtlx2neural.pipeline.plan import plan_materials  # noqa: E402
from mtlx2neural.reference.loading import load_reference  # noqa: E402
from mtlx2neural.scene import find_material, load_asset  # noqa: E402
from mtlx2neural.scene.uv_raster import SPHERE  # noqa: E402
from mtlx2neural.textures.parameter_stack import build_parameter_stack  # noqa: E402
from mtlx2neural.train.config import preset  # noqa: E402

QUAD = """    def Mesh "Quad" (prepend apiSchemas = ["MaterialBindingAPI"])
    {
        double3 xformOp:translate = (10, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
        point3f[] points = [(0, 0, 0), (2, 0, 0), (2, 3, 0), (0, 3, 0)]
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (interpolation = "vertex")
        color3f[] primvars:displayColor = [(0.2, 0.4, 0.6)] (interpolation = "constant")
        rel material:binding = </World/Looks/M>
    }
"""


def stage_text(mesh: str, shaders: str, base_color: str) -> str:
    """A stage with ``mesh`` bound to /World/Looks/M: a standard_surface (base 1) whose base_color
    connects to ``base_color`` (a shader output path under the material) and ``shaders``."""
    return ('#usda 1.0\n(\n    metersPerUnit = 1\n)\ndef Xform "World"\n{\n' + mesh +
            '    def Scope "Looks"\n    {\n        def Material "M"\n        {\n'
            '            token outputs:mtlx:surface.connect = </World/Looks/M/SR.outputs:surface>\n' + shaders +
            '            def Shader "SR"\n            {\n'
            '                uniform token info:id = "ND_standard_surface_surfaceshader"\n'
            '                float inputs:base = 1\n'
            f'                color3f inputs:base_color.connect = </World/Looks/M/{base_color}>\n'
            '                token outputs:surface\n            }\n        }\n    }\n}\n')


def position_shaders(space: str) -> str:
    return ('            def Shader "P"\n            {\n'
            '                uniform token info:id = "ND_position_vector3"\n'
            f'                string inputs:space = "{space}"\n                float3 outputs:out\n            }}\n'
            '            def Shader "C"\n            {\n'
            '                uniform token info:id = "ND_convert_vector3_color3"\n'
            '                float3 inputs:in.connect = </World/Looks/M/P.outputs:out>\n'
            '                color3f outputs:out\n            }\n')


def texel_grid(h, w):
    u = (np.arange(w) + 0.5) / w
    v = 1.0 - (np.arange(h) + 0.5) / h
    uu, vv = np.meshgrid(u, v)
    return uu.ravel(), vv.ravel()  # row-major, top row first: ParameterStack.texel_values' order


def base_color_texels(compiled, res):
    stack = build_parameter_stack(compiled, resolution=res)
    (key,) = [k for k in stack.texel_values(0) if k.endswith("diffuse_bsdf.color")]
    return stack.texel_values(0)[key].numpy()


@pytest.mark.parametrize("space, offset", [("object", 0.0), ("world", 10.0)])
def test_position_bakes_to_the_analytic_mesh_position(tmp_path, space, offset):
    path = tmp_path / "quad.usda"
    path.write_text(stage_text(QUAD, position_shaders(space), "C.outputs:out"))
    src = find_material(str(path))
    assert src.stage_file == str(path) and src.bound_prims == ["/World/Quad"]
    compiled = compile_material(src.document, src.material)
    old = base_color_texels(compiled, (4, 6))  # nothing bound: position is (u, v, 0)
    note = bind_geometry(compiled, src.stage_file, src.bound_prims)
    assert "rasterised from the bound meshes" in note and "/World/Quad" in note
    got = base_color_texels(compiled, (4, 6))
    u, v = texel_grid(4, 6)
    want = np.stack([2 * u + offset, 3 * v, 0 * u], -1)  # the quad maps uv onto [0,2] x [0,3] (+ translate)
    assert np.allclose(got, want, atol=1e-5)  # float32 maps of exact affine values
    assert np.allclose(old, np.stack([u, v, 0 * u], -1), atol=1e-6)
    assert not np.allclose(got, old, atol=0.1)


def test_reference_reads_the_geometry_at_any_uv_bilinearly(tmp_path):
    path = tmp_path / "quad.usda"
    path.write_text(stage_text(QUAD, position_shaders("object"), "C.outputs:out"))
    ref = load_reference(str(path))
    g = torch.Generator().manual_seed(3)
    uv = torch.rand(64, 2, generator=g) * 0.8 + 0.1  # away from the periodic seam, where bilinear wraps
    (value,) = ref.parameters_at(uv).values()
    # Position is affine in uv on this quad, and bilinear lookup reproduces affine functions exactly.
    assert torch.allclose(value, torch.stack([2 * uv[:, 0], 3 * uv[:, 1], 0 * uv[:, 0]], -1), atol=1e-4)
    info = ref.describe()
    assert info["geometry_inputs"] == [{"node": "P", "kind": "position", "space": "object",
                                        "source": "mesh prims /World/Quad"}]


def test_geomcolor_reads_display_color(tmp_path):
    shaders = ('            def Shader "G"\n            {\n'
               '                uniform token info:id = "ND_geomcolor_color3"\n'
               '                color3f outputs:out\n            }\n')
    path = tmp_path / "quad.usda"
    path.write_text(stage_text(QUAD, shaders, "G.outputs:out"))
    src = find_material(str(path))
    compiled = compile_material(src.document, src.material)
    assert base_color_texels(compiled, (2, 2)) == pytest.approx(np.ones((4, 3)))  # unbound: 1, as before
    bind_geometry(compiled, src.stage_file, src.bound_prims)
    assert np.allclose(base_color_texels(compiled, (2, 2)), [0.2, 0.4, 0.6], atol=1e-6)


CUBE_FACES = [  # (corner points, UV cell (column, row) of a 3x2 atlas)
    ([(0.5, -0.5, -0.5), (0.5, 0.5, -0.5), (0.5, 0.5, 0.5), (0.5, -0.5, 0.5)], (0, 0)),  # +x
    ([(-0.5, -0.5, -0.5), (-0.5, -0.5, 0.5), (-0.5, 0.5, 0.5), (-0.5, 0.5, -0.5)], (1, 0)),  # -x
    ([(-0.5, 0.5, -0.5), (-0.5, 0.5, 0.5), (0.5, 0.5, 0.5), (0.5, 0.5, -0.5)], (2, 0)),  # +y
    ([(-0.5, -0.5, -0.5), (0.5, -0.5, -0.5), (0.5, -0.5, 0.5), (-0.5, -0.5, 0.5)], (0, 1)),  # -y
    ([(-0.5, -0.5, 0.5), (0.5, -0.5, 0.5), (0.5, 0.5, 0.5), (-0.5, 0.5, 0.5)], (1, 1)),  # +z
    ([(-0.5, -0.5, -0.5), (-0.5, 0.5, -0.5), (0.5, 0.5, -0.5), (0.5, -0.5, -0.5)], (2, 1)),  # -z
]


def cube_mesh(shift: float) -> str:
    points, st = [], []
    for corners, (c, r) in CUBE_FACES:
        points += corners
        st += [(c / 3, r / 2), ((c + 1) / 3, r / 2), ((c + 1) / 3, (r + 1) / 2), (c / 3, (r + 1) / 2)]
    fmt = ", ".join
    return ('    def Mesh "Cube" (prepend apiSchemas = ["MaterialBindingAPI"])\n    {\n'
            f'        double3 xformOp:translate = ({shift}, 0, 0)\n'
            '        uniform token[] xformOpOrder = ["xformOp:translate"]\n'
            f'        point3f[] points = [{fmt(str(p) for p in points)}]\n'
            f'        int[] faceVertexCounts = [{fmt(["4"] * 6)}]\n'
            f'        int[] faceVertexIndices = [{fmt(str(i) for i in range(24))}]\n'
            f'        texCoord2f[] primvars:st = [{fmt(str(t) for t in st)}] (interpolation = "faceVarying")\n'
            '        rel material:binding = </World/Looks/M>\n    }\n')


def test_triplanar_on_a_cube_reads_world_position_and_normals(tmp_path):
    w = 64
    write_float_image(tmp_path / "x.exr", np.tile(np.array([1.0, 0, 0], np.float32), (4, 4, 1)))
    write_float_image(tmp_path / "y.exr", np.tile(np.array([0, 1.0, 0], np.float32), (4, 4, 1)))
    ramp = ((np.arange(w) + 0.5) / w).astype(np.float32)  # value = u across the image
    write_float_image(tmp_path / "z.exr", np.repeat(np.tile(ramp[None, :, None], (4, 1, 1)), 3, axis=2))
    shaders = ('            def Shader "PW"\n            {\n'
               '                uniform token info:id = "ND_position_vector3"\n'
               '                string inputs:space = "world"\n                float3 outputs:out\n            }\n'
               '            def Shader "T"\n            {\n'
               '                uniform token info:id = "ND_triplanarprojection_color3"\n'
               f'                asset inputs:filex = @{tmp_path / "x.exr"}@\n'
               f'                asset inputs:filey = @{tmp_path / "y.exr"}@\n'
               f'                asset inputs:filez = @{tmp_path / "z.exr"}@\n'
               '                float3 inputs:position.connect = </World/Looks/M/PW.outputs:out>\n'
               '                color3f outputs:out\n            }\n')
    shift = 0.3
    path = tmp_path / "cube.usda"
    path.write_text(stage_text(cube_mesh(shift), shaders, "T.outputs:out"))
    src = find_material(str(path))
    compiled = compile_material(src.document, src.material)
    bind_geometry(compiled, src.stage_file, src.bound_prims)
    kinds = {(r["kind"], r.get("space")) for r in geometry_reads(compiled.graph, compiled.spatial_nodes)}
    assert kinds == {("position", "world"), ("normal", "object")}
    h, wd = 8, 12
    got = base_color_texels(compiled, (h, wd)).reshape(h, wd, 3)
    # +x face (atlas cell (0, 0): bottom-left) is filex's red; +y (cell (2, 0)) filey's green.
    assert np.allclose(got[4:, 0:4], [1, 0, 0], atol=1e-4)  # one-hot blend weights on axis-aligned faces
    assert np.allclose(got[4:, 8:12], [0, 1, 0], atol=1e-4)
    # +z face (cell (1, 1): top middle): filez at world (x, y), the ramp gives frac(x_world).
    u, v = texel_grid(h, wd)
    x_world = (u.reshape(h, wd) * 3 - 1) - 0.5 + shift  # cell column 1 spans x in [-0.5, 0.5] object
    face = got[:4, 4:8, 0]
    want = np.mod(x_world[:4, 4:8], 1.0)
    # Level 0 averages sub-texel samples (the ramp is finer than the grid): keep the texels whose
    # footprint (3 / wd wide in x) stays clear of the ramp's periodic wrap, where the mean is linear.
    half = 1.5 / wd + 1.0 / w
    inner = (want > half) & (want < 1 - half)
    assert inner.sum() >= 8
    assert np.allclose(face[inner], want[inner], atol=1e-4)  # a float ramp, bilinear: exact up to rounding
    assert not np.allclose(face[inner], np.mod(x_world[:4, 4:8] - shift, 1.0)[inner], atol=0.1)  # not object


def test_mtlx_graph_reading_position_uses_the_unit_sphere_with_a_note(tmp_path):
    doc = document('  <position name="P" type="vector3" />\n'
                   '  <convert name="C" type="color3">\n    <input name="in" type="vector3" nodename="P" />\n'
                   '  </convert>\n', standard_surface("M", "SR", base=1.0, base_color={"node": "C"}))
    path = tmp_path / "pos.mtlx"
    path.write_text(doc)
    ref = load_reference(str(path))
    info = ref.describe()
    assert info["geometry_inputs"][0]["source"] == SPHERE
    notes = [a for a in info["approximations"] if "unit sphere" in a]
    assert len(notes) == 1 and "position" in notes[0]
    uv = torch.tensor([[0.5, 0.5], [0.75, 0.5], [0.5, 0.9]])
    (value,) = ref.parameters_at(uv).values()
    # Sphere layout: u = 0.5 + atan2(x, z) / 2pi, v = acos(-y) / pi; at the 256 grid's default lookup
    # points between texel centres bilinear lerp along the sphere gives ~1e-4 chord error.
    phi, theta = (uv[:, 0] - 0.5) * 2 * math.pi, uv[:, 1] * math.pi
    want = torch.stack([theta.sin() * phi.sin(), -theta.cos(), theta.sin() * phi.cos()], -1)
    assert torch.allclose(value, want, atol=1e-3)


def test_a_graph_reading_no_geometry_binds_nothing(tmp_path):
    doc = mx.createDocument()
    mx.readFromXmlString(doc, document(standard_surface("M", "SR", base_color=(0.5, 0.5, 0.5),
                                                         specular_anisotropy=0.5, specular_rotation=0.25)))
    compiled = compile_material(doc, "M")
    # standard_surface rotates Tworld about Nworld: that builds the BSDF's frame, the local axes.
    assert geometry_reads(compiled.graph, compiled.spatial_nodes) == []
    assert bind_geometry(compiled, None, []) is None and compiled.evaluator.geometry is None
    assert compiled.describe()["geometry_inputs"] == []


def test_normal_read_by_maths_is_spatial_and_the_frame_stays_local(tmp_path):
    """An up-facing mask (dot(N_world, +y)) reads the mesh's normal; the BSDF's own normal stays +z."""
    doc = mx.createDocument()
    mx.readFromXmlString(doc, document(
        '  <normal name="N" type="vector3">\n    <input name="space" type="string" value="world" />\n'
        '  </normal>\n'
        '  <dotproduct name="D" type="float">\n    <input name="in1" type="vector3" nodename="N" />\n'
        '    <input name="in2" type="vector3" value="0, 1, 0" />\n  </dotproduct>\n',
        standard_surface("M", "SR", base=1.0, base_color=(1.0, 1.0, 1.0), specular_roughness={"node": "D", "type": "float"})))
    compiled = compile_material(doc, "M")
    reads = geometry_reads(compiled.graph, compiled.spatial_nodes)
    assert [(r["kind"], r["space"]) for r in reads] == [("normal", "world")]
    bind_geometry(compiled, None, [])  # the sphere: its world normal is the point itself
    ev = compiled.evaluator
    d = next(i for i, n in enumerate(compiled.graph.nodes) if n.path == "D")
    uv = torch.tensor([[0.5, 0.25], [0.3, 0.5], [0.7, 0.75]])
    value = ev.run(ev.spatial_closure([Ref(d)]), uv)[(d, "out")][:, 0]
    # Sphere: N_world.y = -cos(pi v); bilinear between texel centres of the 256 grid: ~1e-4.
    assert torch.allclose(value, -torch.cos(math.pi * uv[:, 1]), atol=1e-3)
    lobe_normals = [i for k, i, _ in compiled.parameters() if k.endswith(".normal")]
    assert lobe_normals and all(ev.is_constant(i) for i in lobe_normals)  # the BSDF frame stays local


def test_compiled_output_reads_a_given_normal():
    """The per-point oracle's torch side: ``normal=`` reaches a normal node read by maths."""
    # Local: only this test compiles a bare node output.
    from mtlx2neural.graph.node_eval import compile_output

    doc = mx.createDocument()
    mx.readFromXmlString(doc, document(
        '  <normal name="N" type="vector3" />\n'
        '  <dotproduct name="D" type="float">\n    <input name="in1" type="vector3" nodename="N" />\n'
        '    <input name="in2" type="vector3" value="0, 1, 0" />\n  </dotproduct>\n'))
    out = compile_output(doc, "D")
    g = torch.Generator().manual_seed(5)
    n = torch.nn.functional.normalize(torch.randn(16, 3, generator=g), dim=-1)
    uv = torch.rand(16, 2, generator=g)
    assert torch.allclose(out(uv, normal=n)[:, 0], n[:, 1], atol=1e-6)  # a float32 dot product
    assert torch.allclose(out(uv)[:, 0], torch.zeros(16))  # default +z: no y component


# ---------------------------------------------------------------- UV sets: one layout, other sets as primvars

def uv_image_stage(tmp_path, reader: str, primvars: str) -> str:
    """A quad with the texCoord2f primvars ``primvars`` bound to a material whose base colour is an image
    (a u ramp) read at the texture coordinates of ``reader`` (shader "UV")."""
    w = 16
    ramp = ((np.arange(w) + 0.5) / w).astype(np.float32)
    write_float_image(tmp_path / "ramp.exr", np.repeat(np.tile(ramp[None, :, None], (2, 1, 1)), 3, axis=2))
    mesh = QUAD.replace('        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (interpolation = "vertex")\n',
                        primvars)
    shaders = (reader + '            def Shader "I"\n            {\n'
               '                uniform token info:id = "ND_image_color3"\n'
               f'                asset inputs:file = @{tmp_path / "ramp.exr"}@\n'
               '                float2 inputs:texcoord.connect = </World/Looks/M/UV.outputs:out>\n'
               '                color3f outputs:out\n            }\n')
    return stage_text(mesh, shaders, "I.outputs:out")


def primvar_reader(name: str) -> str:
    return ('            def Shader "UV"\n            {\n'
            '                uniform token info:id = "ND_geompropvalue_vector2"\n'
            f'                string inputs:geomprop = "{name}"\n                float2 outputs:out\n            }}\n')


def texcoord_reader(index: int) -> str:
    return ('            def Shader "UV"\n            {\n'
            '                uniform token info:id = "ND_texcoord_vector2"\n'
            f'                int inputs:index = {index}\n                float2 outputs:out\n            }}\n')


ST = '        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (interpolation = "vertex")\n'
ST1 = '        texCoord2f[] primvars:st1 = [(0, 0), (0.5, 0), (0.5, 1), (0, 1)] (interpolation = "vertex")\n'
UVMAP = ST.replace("primvars:st ", "primvars:UVMap ")


@pytest.mark.parametrize("reader", [texcoord_reader(1), primvar_reader("st1")], ids=["texcoord_index_1", "primvar_st1"])
def test_another_uv_set_is_read_from_its_own_primvar(tmp_path, reader):
    """st1 maps the quad onto the left half of the ramp (u1 = u / 2): a texture read through texcoord index 1
    or the primvar st1 shows u / 2 at every texel of the st layout, where st (index 0) shows u."""
    path = tmp_path / "st1.usda"
    path.write_text(uv_image_stage(tmp_path, reader, ST + ST1))
    src = find_material(str(path))
    compiled = compile_material(src.document, src.material)
    bind_geometry(compiled, src.stage_file, src.bound_prims)
    assert compiled.graph[next(i for i in compiled.spatial_nodes
                               if compiled.graph[i].path.endswith("UV"))].attrs["primvar"] == "st1"
    texels = base_color_texels(compiled, (2, 8))
    u, _ = texel_grid(2, 8)
    # Bilinear samples of a 16-texel linear ramp at u / 2, in the ramp's interior: exact up to float32.
    assert np.allclose(texels[:, 0], u / 2, atol=1e-5), texels[:, 0]
    assert "st1" in {r.get("primvar") for r in compiled.describe()["geometry_inputs"]}


def test_a_uv_set_a_mesh_lacks_is_an_error_and_a_partial_failure(tmp_path):
    path = tmp_path / "st1.usda"
    path.write_text(uv_image_stage(tmp_path, texcoord_reader(1), ST))
    src = find_material(str(path))
    compiled = compile_material(src.document, src.material)
    with pytest.raises(InputError) as err:
        bind_geometry(compiled, src.stage_file, src.bound_prims)
    text = str(err.value)
    assert "material 'M'" in text and "texcoord index 1" in text and "/World/Quad" in text and "st1" in text
    failures = []
    plans = plan_materials(load_asset(str(path)).materials, preset("fast"), failures=failures)
    assert plans == [] and len(failures) == 1 and failures[0].material == "/World/Looks/M"
    assert "st1" in failures[0].reason


def test_another_uv_set_without_bound_meshes_is_a_clear_error(tmp_path):
    """Nothing merged silently: evaluating a texcoord index 1 that no mesh was bound to names the node."""
    path = tmp_path / "st1.usda"
    path.write_text(uv_image_stage(tmp_path, texcoord_reader(1), ST + ST1))
    src = find_material(str(path))
    compiled = compile_material(src.document, src.material)
    with pytest.raises(InputError, match="texcoord index 1"):
        base_color_texels(compiled, (2, 8))


def test_a_udim_texture_through_another_uv_set_is_an_error(tmp_path):
    path = tmp_path / "udim.usda"
    text = uv_image_stage(tmp_path, texcoord_reader(1), ST + ST1)
    (tmp_path / "ramp.exr").rename(tmp_path / "ramp.1001.exr")
    path.write_text(text.replace("ramp.exr@", "ramp.<UDIM>.exr@"))
    src = find_material(str(path))
    compiled = compile_material(src.document, src.material)
    with pytest.raises(InputError, match="UDIM"):
        bind_geometry(compiled, src.stage_file, src.bound_prims)


def test_a_primvar_that_is_the_layouts_uv_set_reads_the_layout(tmp_path):
    # The mesh has only UVMap (no st): its layout is drawn from UVMap, so reading UVMap is reading uv.
    by_name, by_index = tmp_path / "a", tmp_path / "b"
    by_name.mkdir(), by_index.mkdir()
    texels = []
    for folder, reader in ((by_name, primvar_reader("UVMap")), (by_index, texcoord_reader(0))):
        path = folder / "uvmap.usda"
        path.write_text(uv_image_stage(folder, reader, UVMAP))
        src = find_material(str(path))
        compiled = compile_material(src.document, src.material)
        bind_geometry(compiled, src.stage_file, src.bound_prims)
        texels.append(base_color_texels(compiled, (2, 8)))
    u, _ = texel_grid(2, 8)
    assert np.allclose(texels[0], texels[1], atol=0) and np.allclose(texels[0][:, 0], u, atol=1e-6)


def test_a_mtlx_graph_reading_a_uv_primvar_fails_on_the_sphere(tmp_path):
    doc = document('  <geompropvalue name="UV" type="vector2">\n    <input name="geomprop" type="string" value="st1" />\n'
                   '  </geompropvalue>\n  <image name="I" type="color3">\n'
                   '    <input name="texcoord" type="vector2" nodename="UV" />\n  </image>\n',
                   standard_surface("M", "SR", base=1.0, base_color={"node": "I"}))
    path = tmp_path / "st1.mtlx"
    path.write_text(doc)
    with pytest.raises(InputError, match="unit sphere"):
        load_reference(str(path))
