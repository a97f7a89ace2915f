"""geompropvalueuniform (and the string pass-through nodes): a string or filename read from a uniform primvar.

MaterialX 1.39.5 defines geompropvalueuniform for string and filename only.  A baked material has one
value for every geometry, so the node folds to its ``default`` when the graph is expanded
(mtlx2neural.graph.expand.STRING_PASS, with a note); an image whose file comes from it is then an
ordinary image: its file is checked and read when the material is compiled.

Oracle case: a filename geompropvalueuniform feeding an image, sampled at 128 seeded uv in [-2, 2]^2
(periodic wrapping, bilinear), against MaterialX's generated Slang code, which reads the file from a
texture uniform the renderer binds from the geometry; the oracle's probe geometry has no primvars, so it
binds the node's default file (mtlx2neural.oracle.source._geomprop_default), as the node specifies.
Tolerance: 2e-4 absolute.  Both sides interpolate the same 8-bit texels bilinearly in float32, but they
wrap and scale uv to texel coordinates in a different order: at |u| up to 2 on a 640-texel image the
coordinate is near 1280, where a float32 step is 1.2e-4 texel, and the texels differ by up to 1 between
neighbours (the grid's lines), so the result may differ by about 1.2e-4 (measured max 6.0e-5).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import shared_path
from node_oracle import points, require_oracle

from mtlx2neural.errors import InputError
from mtlx2neural.graph.compile import compile_material
from mtlx2neural.graph.node_eval import compile_output
from mtlx2neural.oracle.points import mtlx_node_eval

mx = pytest.importorskip("MaterialX")

ORACLE_CATEGORIES = ("geompropvalueuniform",)
ATOL = 2e-4  # see the module docstring


def _doc(body: str):
    doc = mx.createDocument()
    mx.readFromXmlString(doc, f'<?xml version="1.0"?>\n<materialx version="1.39">\n{body}\n</materialx>\n')
    return doc


def _image_from_primvar(path: str) -> str:
    return (f'<texcoord name="t" type="vector2"/>'
            f'<geompropvalueuniform name="f" type="filename"><input name="geomprop" type="string" value="texfile"/>'
            f'<input name="default" type="filename" value="{path}"/></geompropvalueuniform>'
            f'<image name="img" type="color3"><input name="file" type="filename" nodename="f"/>'
            f'<input name="texcoord" type="vector2" nodename="t"/></image>')


@pytest.mark.slow
def test_filename_primvar_image_matches_materialx_oracle():
    require_oracle()
    tex = shared_path("materialx", "resources", "Images", "grid.png")
    doc = _doc(_image_from_primvar(str(tex)))
    uv, pos = points(128, seed=70, uv_span=2.0)
    want = mtlx_node_eval(doc, "img", uv.astype(np.float64), pos.astype(np.float64))
    got = compile_output(doc, "img")(torch.from_numpy(uv)).numpy()
    assert float(np.ptp(want)) > 0.5, "the oracle's image hardly varies (vacuous test)"
    np.testing.assert_allclose(got, want, atol=ATOL, rtol=0)


def test_uniform_primvar_folds_to_its_default_with_a_note(tmp_path):
    missing = tmp_path / "nope.png"
    body = _image_from_primvar(str(missing)) + (
        '<standard_surface name="s" type="surfaceshader"><input name="base_color" type="color3" nodename="img"/>'
        '</standard_surface><surfacematerial name="m" type="material">'
        '<input name="surfaceshader" type="surfaceshader" nodename="s"/></surfacematerial>')
    # The file is a constant of the compiled graph: a missing one is the usual load-time error.
    with pytest.raises(InputError, match="nope.png"):
        compile_material(_doc(body))
    compiled = compile_material(_doc(body), allow_missing_textures=True)
    notes = compiled.describe()["approximations"]
    assert any("uniform primvar 'texfile'" in n and "nope.png" in n for n in notes), notes


def test_string_pass_through_nodes_are_constants():
    body = ('<constant name="c" type="string"><input name="value" type="string" value="abc"/></constant>'
            '<dot name="d" type="filename"><input name="in" type="filename" value="x.png"/></dot>'
            '<UsdPrimvarReader name="u" type="string"><input name="varname" type="string" value="tag"/>'
            '<input name="fallback" type="string" value="zz"/></UsdPrimvarReader>')
    from mtlx2neural.graph.compile import NATIVE
    from mtlx2neural.graph.expand import Expander, _drive, _Scope
    from mtlx2neural.graph.ir import Const

    exp = Expander(_doc(body), NATIVE)
    scope = _Scope(exp.doc, "")
    got = {n: _drive(exp._node_output(scope, n, "")) for n in ("c", "d", "u")}
    assert got["c"] == Const("abc", "string")
    assert isinstance(got["d"], Const) and got["d"].value.endswith("x.png")
    assert got["u"] == Const("zz", "string")  # UsdPrimvarReader_string -> geompropvalueuniform's default
    assert not exp.graph.nodes  # nothing left to evaluate
