"""MaterialX's noise family compiled to torch (mtlx2neural.graph.noise), checked against MaterialX's own
generated Slang code at many points (the per-point node oracle, mtlx2neural.oracle.points).

Every category (noise2d/3d, fractal2d/3d, cellnoise2d/3d, worleynoise2d/3d, unifiednoise2d/3d, randomfloat,
randomcolor) and every output type is compared at 256 seeded points: uv in [-6, 6]^2 and positions in
[-7, 7]^3, so that floor() of negative coordinates and many lattice cells are exercised.  Each document
below compiles one oracle shader for all of its nodes.

Tolerance: 1e-6 absolute.  Both sides run the same float32 operations in the same order on the same 32-bit
integer hashes, so they agree bit for bit except in the last bit of a square root (Worley distances) or a
sine/cosine (unifiednoise's jitter rotation; the rotate2d/rotate3d checks are relative to their
magnitude): measured max 1.2e-7.  Worley noise could differ more where
two feature points are at exactly the same distance (the nearest one is then a matter of rounding); at
random float points such ties have probability zero, and none occurs at these seeds.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import shared_path
from node_oracle import require_oracle

from mtlx2neural.graph.node_eval import compile_output
from mtlx2neural.graph.noise import cell_noise, hash_ints, perlin, worley
from mtlx2neural.oracle.points import mtlx_node_eval

mx = pytest.importorskip("MaterialX")

ATOL = 1e-6  # see the module docstring
N = 256

SOURCES = """  <position name="p" type="vector3"/>
  <texcoord name="t" type="vector2"/>
  <extract name="tx" type="float"><input name="in" type="vector2" nodename="t"/><input name="index" type="integer" value="0"/></extract>
  <floor name="ti" type="integer"><input name="in" type="float" nodename="tx"/></floor>
  <clamp name="oct_f" type="float"><input name="in" type="float" nodename="tx"/><input name="low" type="float" value="0"/><input name="high" type="float" value="4"/></clamp>
  <ceil name="oct" type="integer"><input name="in" type="float" nodename="oct_f"/></ceil>
"""


def _node(name: str, category: str, mx_type: str, **inputs) -> str:
    body = []
    for key, (typ, value) in inputs.items():
        if isinstance(value, str) and value.startswith("@"):
            body.append(f'<input name="{key}" type="{typ}" nodename="{value[1:]}"/>')
        else:
            body.append(f'<input name="{key}" type="{typ}" value="{value}"/>')
    return f'  <{category} name="{name}" type="{mx_type}">{"".join(body)}</{category}>\n'


def _document(nodes: list[str]) -> str:
    return '<?xml version="1.0"?>\n<materialx version="1.39">\n' + SOURCES + "".join(nodes) + "</materialx>\n"


AMPLITUDE = {"float": "0.8", "vector2": "0.8, 1.3", "vector3": "0.8, 1.3, 0.5", "vector4": "0.8, 1.3, 0.5, 2.0"}
AMP_TYPE = {"float": "float", "vector2": "vector2", "vector3": "vector3", "color3": "vector3",
            "vector4": "vector4", "color4": "vector4"}


def _perlin_family(dim: str) -> list[str]:
    coord = ("texcoord", ("vector2", "@t")) if dim == "2d" else ("position", ("vector3", "@p"))
    nodes = []
    for typ in ("float", "vector2", "vector3", "vector4", "color3", "color4"):
        amp_type = AMP_TYPE[typ]
        for fa in ((False, True) if typ != "float" else (False,)):
            at = "float" if fa else amp_type
            suffix = "FA" if fa else ""
            nodes.append(_node(f"noise{dim}_{typ}{suffix}", f"noise{dim}", typ, **{coord[0]: coord[1]},
                               amplitude=(at, AMPLITUDE[at]), pivot=("float", "0.25")))
            nodes.append(_node(f"fractal{dim}_{typ}{suffix}", f"fractal{dim}", typ, **{coord[0]: coord[1]},
                               amplitude=(at, AMPLITUDE[at]), octaves=("integer", "4"),
                               lacunarity=("float", "2.1"), diminish=("float", "0.55")))
    # Octaves varying per point (0 to 4), read from the uv.
    nodes.append(_node(f"fractal{dim}_octaves", f"fractal{dim}", "vector3", **{coord[0]: coord[1]},
                       octaves=("integer", "@oct")))
    nodes.append(_node(f"cellnoise{dim}", f"cellnoise{dim}", "float", **{coord[0]: coord[1]}))
    for typ in ("float", "vector2", "vector3"):
        for style in (0, 1):
            for jitter in ("1.0", "0.6"):
                nodes.append(_node(f"worleynoise{dim}_{typ}_s{style}_j{jitter[-1]}", f"worleynoise{dim}", typ,
                                   **{coord[0]: coord[1]}, style=("integer", str(style)),
                                   jitter=("float", jitter)))
    return nodes


def _unified_and_random() -> list[str]:
    nodes = []
    for kind in range(4):
        nodes.append(_node(f"unified2d_{kind}", "unifiednoise2d", "float", texcoord=("vector2", "@t"),
                           type=("integer", str(kind)), freq=("vector2", "1.5, 2"),
                           offset=("vector2", "0.3, -0.2")))
        nodes.append(_node(f"unified3d_{kind}", "unifiednoise3d", "float", position=("vector3", "@p"),
                           type=("integer", str(kind)), outmin=("float", "-0.5"),
                           clampoutput=("boolean", "false"), jitter=("float", "0.8")))
    nodes.append(_node("unified2d_worley_solid", "unifiednoise2d", "float", texcoord=("vector2", "@t"),
                       type=("integer", "2"), style=("integer", "1"), jitter=("float", "0.7")))
    nodes.append(_node("randomfloat_float", "randomfloat", "float", **{"in": ("float", "@tx")},
                       min=("float", "-2"), seed=("integer", "5")))
    nodes.append(_node("randomfloat_integer", "randomfloat", "float", **{"in": ("integer", "@ti")},
                       seed=("integer", "3")))
    nodes.append(_node("randomcolor_float", "randomcolor", "color3", **{"in": ("float", "@tx")},
                       saturationlow=("float", "0.2"), brightnesslow=("float", "0.3")))
    nodes.append(_node("randomcolor_integer", "randomcolor", "color3", **{"in": ("integer", "@ti")},
                       seed=("integer", "7")))
    # unifiednoise's jitter rotates the coordinates: MaterialX's rotate2d/3d turn clockwise.
    nodes.append(_node("rotate2d", "rotate2d", "vector2", **{"in": ("vector2", "@t")}, amount=("float", "30")))
    nodes.append(_node("rotate3d", "rotate3d", "vector3", **{"in": ("vector3", "@p")}, amount=("float", "-47"),
                       axis=("vector3", "0.1, 1, 0.3")))
    return nodes


def _names(nodes: list[str]) -> list[str]:
    return [n.split('name="', 1)[1].split('"', 1)[0] for n in nodes]


def _points(seed: int):
    # float32-representable, so that both sides see exactly these coordinates
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-6.0, 6.0, (N, 2)).astype(np.float32)
    pos = rng.uniform(-7.0, 7.0, (N, 3)).astype(np.float32)
    return uv, pos


@pytest.mark.parametrize("family", ["2d", "3d", "unified_random"])
def test_noise_matches_materialx_oracle(family):
    require_oracle()
    nodes = _unified_and_random() if family == "unified_random" else _perlin_family(family)
    doc = mx.createDocument()
    mx.readFromXmlString(doc, _document(nodes))
    names = _names(nodes)
    uv, pos = _points(seed={"2d": 11, "3d": 12, "unified_random": 13}[family])
    expected = mtlx_node_eval(doc, names, uv.astype(np.float64), pos.astype(np.float64))
    errors = {}
    for name, want in zip(names, expected):
        got = compile_output(doc, name)(torch.from_numpy(uv), torch.from_numpy(pos)).numpy()
        assert got.shape == want.shape, name
        assert np.ptp(want) > 0.05, f"{name}: the oracle's values hardly vary; the test would be vacuous"
        # Rotated coordinates reach |12|, where a float32 ulp is 1e-6: relative tolerance for them.
        scale = max(1.0, float(np.abs(want).max())) if name.startswith("rotate") else 1.0
        errors[name] = float(np.abs(got - want).max()) / scale
    bad = {k: v for k, v in errors.items() if v > ATOL}
    assert not bad, f"max |torch - MaterialX| above {ATOL}: {bad}"


# --- properties that need no oracle -------------------------------------------------------------


def test_hash_wraps_like_unsigned_32_bit():
    x = torch.tensor([-(2**31), -1, 0, 1, 2**31 - 1], dtype=torch.int64)
    h = hash_ints(x, -x, x * 3)
    assert h.dtype == torch.int64
    assert bool(((h >= 0) & (h < 2**32)).all())
    # Deterministic, and different lattice points give different hashes.
    assert torch.equal(h, hash_ints(x, -x, x * 3))
    assert len(set(h.tolist())) == 5


def test_perlin_is_zero_on_the_lattice_and_cells_are_constant():
    g = torch.Generator().manual_seed(0)
    ints = torch.randint(-50, 50, (64, 3), generator=g).to(torch.float32)
    # Gradient noise vanishes at lattice points (every corner's gradient is dotted with a zero offset).
    assert torch.equal(perlin(ints, 1), torch.zeros(64, 1))
    assert torch.equal(perlin(ints[:, :2], 3), torch.zeros(64, 3))
    # Cellular noise is constant over a cell and in [0, 1].
    inside = ints + torch.rand(64, 3, generator=g) * 0.99
    assert torch.equal(cell_noise(ints), cell_noise(inside))
    assert bool(((cell_noise(inside) >= 0) & (cell_noise(inside) <= 1)).all())


def test_worley_without_jitter_is_distance_to_cell_centres():
    g = torch.Generator().manual_seed(1)
    p = torch.rand(128, 2, generator=g) * 8 - 4
    zero = torch.zeros(1, 1)
    d = worley(p, zero, zero, 1)
    # With jitter 0 every feature point is its cell's centre, so the nearest is the own cell's.
    centre = torch.floor(p) + 0.5
    # float32 distance of two float32 points: a few ulps of values below 1.
    torch.testing.assert_close(d[:, 0], (p - centre).norm(dim=1), atol=1e-6, rtol=0)


def test_marble_graph_matches_oracle_at_many_points():
    """Marble_3D's colour graph (position -> fractal3d -> sin -> power -> mix) at 128 points; the
    whole-material oracle test sees one point, (0.5, 0.5, 0), where the scaled position is a lattice point
    and the fractal term vanishes."""
    require_oracle()
    path = shared_path("materialx", "resources", "Materials", "Examples", "StandardSurface",
                       "standard_surface_marble_solid.mtlx")
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(path))
    rng = np.random.default_rng(21)
    pos = rng.uniform(-1.5, 1.5, (128, 3)).astype(np.float32)
    uv = np.zeros((128, 2), dtype=np.float32)
    want = mtlx_node_eval(doc, "NG_marble1", uv, pos)
    got = compile_output(doc, "NG_marble1")(torch.from_numpy(uv), torch.from_numpy(pos)).numpy()
    assert np.ptp(want) > 0.1
    # The same float32 operations on both sides (measured: identical); sin and pow may differ in the last
    # bit between torch and the compiled shader, which the cube and the mix keep below 1e-6.
    np.testing.assert_allclose(got, want, atol=1e-6, rtol=0)
