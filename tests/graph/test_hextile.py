"""MaterialX's hex-tiling nodes compiled to torch (mtlx2neural.graph.hextile: hextiledimage color3/color4,
hextilednormalmap), checked against MaterialX's own generated code at 256 seeded uv points (the per-point
node oracle, mtlx2neural.oracle.points) over [-3, 3]^2, i.e. dozens of tiles and their random rotations,
scales and offsets.

Settings cover the defaults, Schlick's gain (falloff != 0.5), the luminance contrast, tiling, rotation,
scale and offset ranges, a colour-managed texture (srgb_texture into lin_rec709), flip_g, strength and
tilted surface normals.  Textures are random 16x16 EXRs (colours in [0.05, 1]; encoded normals of the
upper hemisphere), read bilinearly at full resolution on both sides (the oracle's derivatives are zero).

Tolerances: colours 2e-5 + 1e-5 rel: the same float32 arithmetic, but the tiles' texture coordinates
(rotated, divided by the scale, up to ~20 in magnitude) round differently in the last bit between torch and
the shader, which moves bilinear reads by ~1e-6 per texel step of up to ~1 (measured max 1.1e-5, on the
tiled and gained case).  Normals 5e-5: the surface-gradient blend divides by N . N_i and normalises
(measured max 1.2e-5).
"""

from __future__ import annotations

import MaterialX as mx
import numpy as np
import pytest
import torch
from conftest import write_float_image
from node_oracle import points, require_oracle

from mtlx2neural.errors import InputError
from mtlx2neural.graph import compile_material
from mtlx2neural.graph.node_eval import compile_output
from mtlx2neural.oracle.points import mtlx_node_eval

ORACLE_CATEGORIES = ("hextiledimage", "hextilednormalmap")
COLOUR_ATOL, COLOUR_RTOL = 2e-5, 1e-5  # see the module docstring
NORMAL_ATOL = 5e-5

COLOUR_CASES = {
    "defaults": ("color3", {}),
    "gain_contrast": ("color3", {"falloff": 0.8, "falloffcontrast": 1.0, "tiling": mx.Vector2(2.0, 3.0),
                                 "rotationrange": mx.Vector2(-30.0, 90.0), "scalerange": mx.Vector2(0.7, 1.5),
                                 "offset": 0.5}),
    "rgba_soft": ("color4", {"falloff": 0.3, "rotation": 0.5, "scale": 0.25,
                             "offsetrange": mx.Vector2(-0.5, 0.25)}),
    "srgb": ("color3", {"falloff": 0.6}),
}
NORMAL_CASES = {
    "defaults": {},
    "flip_strength": {"strength": 0.6, "flip_g": True, "falloff": 0.7, "tiling": mx.Vector2(1.5, 1.5)},
}


def _textures(tmp_path):
    rng = np.random.default_rng(80)
    colour = rng.uniform(0.05, 1.0, size=(16, 16, 4)).astype(np.float32)
    write_float_image(tmp_path / "colour.exr", colour)
    d = rng.normal(size=(16, 16, 3))
    d[..., 2] = np.abs(d[..., 2]) + 0.5
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    write_float_image(tmp_path / "normal.exr", (d * 0.5 + 0.5).astype(np.float32))
    return tmp_path / "colour.exr", tmp_path / "normal.exr"


def _document(colour, normal):
    doc = mx.createDocument()
    doc.setColorSpace("lin_rec709")
    targets = []
    for name, (typ, values) in COLOUR_CASES.items():
        n = doc.addNode("hextiledimage", f"img_{name}", typ)
        f = n.setInputValue("file", str(colour), "filename")
        if name == "srgb":
            f.setColorSpace("srgb_texture")
        for k, v in values.items():
            n.setInputValue(k, v)
        targets.append(n.getName())
    for name, values in NORMAL_CASES.items():
        n = doc.addNode("hextilednormalmap", f"nrm_{name}", "vector3")
        n.setInputValue("file", str(normal), "filename")
        for k, v in values.items():
            n.setInputValue(k, v)
        targets.append(n.getName())
    return doc, targets


@pytest.mark.slow
@pytest.mark.parametrize("tilted", [False, True])
def test_hextiled_nodes_match_materialx_oracle(tmp_path, tilted):
    require_oracle()
    doc, targets = _document(*_textures(tmp_path))
    uv, pos = points(256, seed=81)
    normal = None
    if tilted:  # unit normals within ~50 degrees of +z (tangent +x and bitangent +y stay, as the oracle's)
        rng = np.random.default_rng(82)
        normal = np.concatenate([rng.uniform(-0.8, 0.8, (256, 2)), np.ones((256, 1))], -1)
        normal = (normal / np.linalg.norm(normal, axis=-1, keepdims=True)).astype(np.float32)
    want = mtlx_node_eval(doc, targets, uv.astype(np.float64), pos.astype(np.float64), normal=normal)
    errors = {}
    for name, expected in zip(targets, want):
        out = compile_output(doc, name)
        got = out(torch.from_numpy(uv), torch.from_numpy(pos),
                  None if normal is None else torch.from_numpy(normal)).numpy().astype(np.float64)
        assert got.shape == expected.shape, name
        assert float(np.ptp(expected, 0).min()) > 0.1, f"{name}: the oracle's values hardly vary (vacuous)"
        if name.startswith("img_"):
            errors[name] = float((np.abs(got - expected) / (COLOUR_ATOL + COLOUR_RTOL * np.abs(expected))).max())
        else:
            errors[name] = float(np.abs(got - expected).max() / NORMAL_ATOL)
    bad = {k: v for k, v in errors.items() if v > 1.0}
    assert not bad, f"|torch - MaterialX| above tolerance (ratio): {bad}"


def test_hextiling_is_seamless_and_without_file_returns_default(tmp_path):
    colour, _ = _textures(tmp_path)
    doc = mx.createDocument()
    n = doc.addNode("hextiledimage", "img", "color3")
    n.setInputValue("file", str(colour), "filename")
    out = compile_output(doc, "img")
    # Continuity: two points 1e-4 apart differ by about a bilinear step (no seams between tiles).
    g = torch.Generator().manual_seed(83)
    uv = torch.rand(2048, 2, generator=g) * 6 - 3
    jump = (out(uv + 1e-4) - out(uv)).abs().max()
    assert float(jump) < 0.05
    # The tiling is not the plain texture: rotated/scaled reads differ from it somewhere.
    plain_doc = mx.createDocument()
    plain = plain_doc.addNode("image", "img", "color3")
    plain.setInputValue("file", str(colour), "filename")
    assert float((out(uv) - compile_output(plain_doc, "img")(uv)).abs().max()) > 0.1
    empty = mx.createDocument()
    e = empty.addNode("hextiledimage", "img", "color3")
    e.setInputValue("default", mx.Color3(0.2, 0.3, 0.4))
    np.testing.assert_array_equal(compile_output(empty, "img")(uv[:4]).numpy(),
                                  np.tile(np.float32([0.2, 0.3, 0.4]), (4, 1)))


def _hextiled_material(file: str):
    doc = mx.createDocument()
    img = doc.addNode("hextiledimage", "tiles", "color3")
    img.setInputValue("file", file, "filename")
    img.setInputValue("default", mx.Color3(0.2, 0.4, 0.6))
    shader = doc.addNode("standard_surface", "SR_tiles", "surfaceshader")
    shader.setConnectedNode("base_color", img)
    doc.addMaterialNode("M_tiles", shader)
    return doc


def test_hextiled_files_are_checked_when_compiled_like_image_files(tmp_path):
    """A missing file names the node at compile time (not at the first bake), --allow-missing-textures
    gives the node's default, and a file named with another case is found, as for `image`."""
    colour, _ = _textures(tmp_path)
    with pytest.raises(InputError, match=r"tiles.*allow-missing-textures"):
        compile_material(_hextiled_material(str(tmp_path / "absent.exr")), "M_tiles")
    lenient = compile_material(_hextiled_material(str(tmp_path / "absent.exr")), "M_tiles", allow_missing_textures=True)
    assert any("absent.exr" in n and "default" in n for n in lenient.program.notes)
    fixed = compile_material(_hextiled_material(str(tmp_path / "COLOUR.exr")), "M_tiles")
    assert len(fixed.case_fixes) == 1 and "COLOUR.exr" in fixed.case_fixes[0] and colour.name in fixed.case_fixes[0]
