"""MaterialX's space transforms compiled to torch (mtlx2neural.graph.transforms), checked against MaterialX's own
generated Slang code at 128 seeded points (the per-point node oracle, mtlx2neural.oracle.points), for every
pair of the space names MaterialX accepts ("", model, object, world).

Object space is world space on both sides (the oracle's object-to-world matrices are the identity), so
what is checked is which transforms apply and that normals are normalised in every case (MaterialX does,
even between equal spaces).  The input vectors follow smooth functions of uv and position, each channel in
[-2, 2] (tests/node_oracle.py).

Tolerance: |torch - MaterialX| <= 1e-6 + 1e-6 |MaterialX|: identity passes are exact; the normalisation
may differ in the last bit (measured max 1.2e-7).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch
from node_oracle import (
    RANGES,
    Builder,
    assert_within,
    compare,
    points,
    require_oracle,
)

from mtlx2neural.graph.library import standard_library
from mtlx2neural.graph.transforms import space_matrix, transform

ORACLE_CATEGORIES = ("transformpoint", "transformvector", "transformnormal")
SPACES = ("", "model", "object", "world")
ATOL = RTOL = 1e-6  # see the module docstring


@pytest.mark.slow
def test_transforms_match_materialx_oracle(monkeypatch):
    require_oracle()
    for c in ORACLE_CATEGORIES:
        monkeypatch.setitem(RANGES, c, (-2.0, 2.0))
    lib = standard_library()
    builder = Builder(seed=80)
    for c in ORACLE_CATEGORIES:
        for f in SPACES:
            for t in SPACES:
                builder.node(lib.getNodeDef(f"ND_{c}_vector3"), f"{c}_{f or 'none'}_{t or 'none'}",
                             values={"fromspace": f, "tospace": t})
    uv, pos = points(128, seed=81)
    results = compare(builder, uv, pos)
    for (name, _), (_, want) in results.items():
        assert float(np.ptp(want)) > 0.5, f"{name}: the oracle's values hardly vary (vacuous test)"
        if name.startswith("transformnormal"):
            np.testing.assert_allclose(np.linalg.norm(want, axis=1), 1.0, atol=1e-6)
    assert_within(results, ATOL, RTOL)


def test_space_matrices_with_a_real_object_to_world():
    g = torch.Generator().manual_seed(3)
    m = torch.eye(4)
    m[:3, :3] = torch.randn(3, 3, generator=g) + 2 * torch.eye(3)
    m[:3, 3] = torch.tensor([1.0, -2.0, 0.5])
    v = torch.randn(16, 3, generator=g)
    p_world = transform(v, "object", "world", "point", m)
    torch.testing.assert_close(transform(p_world, "world", "model", "point", m), v, atol=1e-5, rtol=0)
    # Vectors ignore the translation.
    torch.testing.assert_close(transform(v, "object", "world", "vector", m), v @ m[:3, :3].T)
    # A normal stays perpendicular to a transformed tangent vector.
    n = torch.randn(16, 3, generator=g)
    tangent = torch.linalg.cross(n, torch.randn(16, 3, generator=g), dim=-1)
    n_w = transform(n, "object", "world", "normal", m)
    t_w = transform(tangent, "object", "world", "vector", m)
    assert float((n_w * t_w).sum(-1).abs().max()) < 1e-4
    torch.testing.assert_close(n_w.norm(dim=-1), torch.ones(16))
    # Same space, empty or unknown names: no matrix.
    for f, t in (("world", "world"), ("object", "model"), ("", "world"), ("tangent", "world")):
        assert space_matrix(f, t, "point", m) is None


# ---------------------------------------------------------------- real spaces from the bound mesh
#
# A quad translated (1, -2, 4), turned 30 degrees about z and scaled (2, 3, 0.5) (USD applies the last op
# first to points: scale, then rotate, then translate), bound to a material whose base colour is one
# transform node of a constant.  The expectation is built here from the three factors (row vectors,
# p_world = p S R + T), not read from USD.
ANGLE = math.radians(30.0)
SCALE = np.array([2.0, 3.0, 0.5])
SHIFT = np.array([1.0, -2.0, 4.0])
VALUE = (0.5, 1.0, -1.0)


def object_to_world_rows() -> tuple[np.ndarray, np.ndarray]:
    """(linear part S R [3, 3], translation [3]) in the row-vector convention."""
    c, s = math.cos(ANGLE), math.sin(ANGLE)
    rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # p R turns p by +30 degrees about z
    return np.diag(SCALE) @ rot, SHIFT


def mesh(name: str, translate: str, st: str = "(0, 0), (1, 0), (1, 1), (0, 1)") -> str:
    return (f'    def Mesh "{name}" (prepend apiSchemas = ["MaterialBindingAPI"])\n    {{\n'
            f'        double3 xformOp:translate = {translate}\n        float xformOp:rotateZ = 30\n'
            '        float3 xformOp:scale = (2, 3, 0.5)\n'
            '        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateZ", "xformOp:scale"]\n'
            '        point3f[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]\n'
            '        int[] faceVertexCounts = [4]\n        int[] faceVertexIndices = [0, 1, 2, 3]\n'
            f'        texCoord2f[] primvars:st = [{st}] (interpolation = "vertex")\n'
            '        rel material:binding = </World/Looks/M>\n    }\n')


def transform_stage(category: str, fromspace: str, tospace: str, meshes: str) -> str:
    shaders = ('            def Shader "X"\n            {\n'
               f'                uniform token info:id = "ND_{category}_vector3"\n'
               f'                float3 inputs:in = {VALUE}\n'
               f'                string inputs:fromspace = "{fromspace}"\n'
               f'                string inputs:tospace = "{tospace}"\n                float3 outputs:out\n            }}\n'
               '            def Shader "C"\n            {\n'
               '                uniform token info:id = "ND_convert_vector3_color3"\n'
               '                float3 inputs:in.connect = </World/Looks/M/X.outputs:out>\n'
               '                color3f outputs:out\n            }\n')
    return ('#usda 1.0\n(\n    metersPerUnit = 1\n)\ndef Xform "World"\n{\n' + meshes +
            '    def Scope "Looks"\n    {\n        def Material "M"\n        {\n'
            '            token outputs:mtlx:surface.connect = </World/Looks/M/SR.outputs:surface>\n' + shaders +
            '            def Shader "SR"\n            {\n'
            '                uniform token info:id = "ND_standard_surface_surfaceshader"\n'
            '                color3f inputs:base_color.connect = </World/Looks/M/C.outputs:out>\n'
            '                token outputs:surface\n            }\n        }\n    }\n}\n')


def transformed(path, res=(4, 4)) -> tuple[np.ndarray, object]:
    """(the transform node's value at every texel centre of an (H, W) grid [H*W, 3], row 0 at v = 1; the
    compiled material) of ``path``'s material, bound to its meshes (the evaluator directly: a base colour
    would be clamped to >= 0)."""
    # Local: the scene and geometry modules, for these stage tests only.
    from mtlx2neural.graph import compile_material
    from mtlx2neural.graph.geometry import bind_geometry
    from mtlx2neural.graph.ir import Ref
    from mtlx2neural.scene import find_material

    src = find_material(str(path))
    compiled = compile_material(src.document, src.material)
    bind_geometry(compiled, src.stage_file, src.bound_prims)
    ev = compiled.evaluator
    ev.geometry.resolution = res
    (i,) = [k for k, n in enumerate(compiled.graph.nodes) if n.category.startswith("transform")]
    h, w = res
    u, v = np.meshgrid((np.arange(w) + 0.5) / w, 1.0 - (np.arange(h) + 0.5) / h)
    uv = torch.tensor(np.stack([u.ravel(), v.ravel()], -1), dtype=torch.float32)
    env = ev.run(ev.spatial_closure([Ref(i, "out")]), uv)
    return ev.value(Ref(i, "out"), env).expand(h * w, 3).numpy(), compiled  # folded when one matrix


@pytest.mark.parametrize("category, fromspace, tospace", [
    ("transformpoint", "object", "world"), ("transformpoint", "world", "object"),
    ("transformvector", "model", "world"), ("transformvector", "world", "model"),
    ("transformnormal", "object", "world"), ("transformnormal", "world", "object")])
def test_object_and_world_use_the_bound_meshs_transform(tmp_path, category, fromspace, tospace):
    pytest.importorskip("pxr", reason="usd-core is needed to build the test stage")
    path = tmp_path / "xf.usda"
    path.write_text(transform_stage(category, fromspace, tospace, mesh("Quad", "(1, -2, 4)")))
    got, compiled = transformed(path)
    lin, shift = object_to_world_rows()
    v = np.array(VALUE)
    to_world = tospace == "world"
    if category == "transformpoint":
        want = v @ lin + shift if to_world else (v - shift) @ np.linalg.inv(lin)
    elif category == "transformvector":
        want = v @ lin if to_world else v @ np.linalg.inv(lin)
    else:  # normals: the inverse transpose of the vectors' matrix, then unit length
        want = v @ np.linalg.inv(lin).T if to_world else v @ lin.T
        want = want / np.linalg.norm(want)
    # float32 maps and matrices of values up to ~10: 1e-5 absolute.
    assert np.allclose(got, want[None], atol=1e-5), (got[0], want)
    assert not np.allclose(want, v / (np.linalg.norm(v) if category == "transformnormal" else 1.0), atol=0.1)
    # One bound mesh, one matrix: folded into the node, so the material is uniform again (1x1 latents).
    assert compiled.varying_parameters() == [] and compiled.evaluator.world_transform == [False] * len(
        compiled.graph.nodes)
    assert any("object-to-world matrix is folded" in a for a in compiled.describe()["approximations"])


def test_mtlx_input_keeps_object_space_as_world_space(tmp_path):
    # Local: the MaterialX documents, the IR and the reference loader, for this test only.
    from materials import document, standard_surface

    from mtlx2neural.graph.ir import Ref
    from mtlx2neural.reference.loading import load_reference

    doc = document('  <transformpoint name="X" type="vector3">\n'
                   '    <input name="in" type="vector3" value="0.5, 1, 0.25" />\n'
                   '    <input name="fromspace" type="string" value="object" />\n'
                   '    <input name="tospace" type="string" value="world" />\n  </transformpoint>\n'
                   '  <convert name="C" type="color3">\n    <input name="in" type="vector3" nodename="X" />\n'
                   '  </convert>\n', standard_surface("M", "SR", base=1.0, base_color={"node": "C"}))
    path = tmp_path / "xf.mtlx"
    path.write_text(doc)
    ref = load_reference(str(path))
    assert any("unit sphere" in a for a in ref.describe()["approximations"])
    # The sphere's matrix is the identity, folded: the material stays uniform and the node its input.
    compiled = ref.compiled
    assert compiled.varying_parameters() == []
    (i,) = [k for k, n in enumerate(compiled.graph.nodes) if n.category == "transformpoint"]
    value = compiled.evaluator.value(Ref(i, "out"), {})
    assert torch.allclose(value, torch.tensor([[0.5, 1.0, 0.25]]), atol=1e-6)


def test_overlapping_prims_with_different_transforms_warn_and_the_first_is_used(tmp_path):
    pytest.importorskip("pxr", reason="usd-core is needed to build the test stage")
    path = tmp_path / "two.usda"
    path.write_text(transform_stage("transformpoint", "object", "world",
                                    mesh("A", "(1, -2, 4)") + mesh("B", "(7, 7, 7)")))
    with pytest.warns(UserWarning) as record:
        got, _ = transformed(path)
    text = " ".join(str(r.message) for r in record)
    assert "/World/B" in text and "/World/A" in text and "different object-to-world transform" in text
    lin, shift = object_to_world_rows()
    assert np.allclose(got, (np.array(VALUE) @ lin + shift)[None], atol=1e-5)  # /World/A's, the first bound


def test_prims_side_by_side_in_uv_each_use_their_own_transform(tmp_path):
    pytest.importorskip("pxr", reason="usd-core is needed to build the test stage")
    path = tmp_path / "side.usda"
    # A's UVs cover the left half of UV space, B's the right half: no overlap, each texel its own prim.
    meshes = mesh("A", "(1, -2, 4)", "(0, 0), (0.5, 0), (0.5, 1), (0, 1)")
    meshes += mesh("B", "(7, 7, 7)", "(0.5, 0), (1, 0), (1, 1), (0.5, 1)")
    path.write_text(transform_stage("transformpoint", "object", "world", meshes))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # side by side: no overlap warning
        got, compiled = transformed(path, res=(2, 4))
    lin, _ = object_to_world_rows()
    p = np.array(VALUE) @ lin
    left, right = got.reshape(2, 4, 3)[:, :2], got.reshape(2, 4, 3)[:, 2:]
    assert np.allclose(left, p + SHIFT, atol=1e-5) and np.allclose(right, p + np.array([7.0, 7.0, 7.0]), atol=1e-5)
    # Two matrices: read per sample, so the node is spatial and inspect lists what it reads.
    reads = compiled.describe()["geometry_inputs"]
    assert [(r["kind"], r["space"]) for r in reads] == [("transformpoint", "object to world")]
    assert compiled.varying_parameters() != []
