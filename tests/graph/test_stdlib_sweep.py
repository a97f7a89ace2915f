"""Every other value category that compiles (maths, channels, logic, geometry, colour, pbrlib helpers),
checked against MaterialX's own generated Slang code at 128 seeded points (the per-point node oracle,
mtlx2neural.oracle.points).

Each group below is one document holding one node per drivable nodedef of its categories (every output
type MaterialX defines but matrices, which tests/graph/test_matrix.py reads through vectors; cmlib's matrix
colour transforms are a group), each numeric input following a smooth function of uv (in [-3, 3]^2) and position (in [-3, 3]^3) over [0.1, 0.9] (positive and away from 0 and 1,
so divisions, logarithms, arc sines and powers stay in their domains), over [-3, 3] for the rounding and
sign functions and [-4, 4] for integer inputs (tests/node_oracle.py).  Outputs that are constant by nature
(the geometric frame of the flat stand-in surface, time and frame) are listed in CONSTANT; every other
node must have an output that varies over the points (the shading-model translators have outputs that
are constants by design).  ifequal's float inputs are whole numbers (floored), so that both
branches occur.

Tolerance: |torch - MaterialX| <= 1e-5 + 1e-5 |MaterialX|.  Both sides run float32 arithmetic, but
transcendental functions (sin, exp, pow, acos...) may differ in the last bits between torch and the
compiled shader, and chains (hsv round trips, normalisations, smoothstep of differences) amplify them a few
times; the groups' measured maxima are in docs/coverage.md.
"""

from __future__ import annotations

import numpy as np
import pytest
from node_oracle import (
    Builder,
    assert_within,
    category_nodes,
    compare,
    points,
    require_oracle,
)

from mtlx2neural.graph.ops import Application

GROUPS = (
    ("absval", "acos", "add", "and", "asin", "atan2", "bitangent", "ceil", "clamp", "combine2"),
    ("combine3", "combine4", "constant", "convert", "cos", "crossproduct", "distance", "divide", "dot",
     "dotproduct"),
    ("exp", "extract", "floor", "fract", "frame", "geomcolor", "hsvtorgb", "ifequal", "ifgreater", "ifgreatereq"),
    ("invert", "ln", "luminance", "magnitude", "max", "min", "mix", "modulo", "multiply", "normal"),
    ("normalize", "not", "or", "position", "power", "remap", "rgbtohsv", "rotate2d", "rotate3d", "round"),
    ("safepower", "separate2", "separate3", "separate4", "sign", "sin", "smoothstep", "sqrt", "subtract", "switch"),
    ("tan", "tangent", "texcoord", "time", "xor", "artistic_ior", "roughness_anisotropy", "roughness_dual",
     "glossiness_anisotropy", "reflect", "refract"),
    ("blur", "checkerboard", "circle", "cloverleaf", "colorcorrect", "contrast", "crosshatch", "grid", "hexagon",
     "hsvadjust"),
    ("line", "normalmap", "place2d", "range", "saturate", "trianglewave", "tiledcircles", "tiledcloverleafs",
     "tiledhexagons"),
    ("g18_rec709_to_lin_rec709", "g22_rec709_to_lin_rec709", "rec709_display_to_lin_rec709",
     "srgb_texture_to_lin_rec709", "UsdTransform2d", "open_pbr_anisotropy"),
    ("acescg_to_lin_rec709", "adobergb_to_lin_rec709", "g22_ap1_to_lin_rec709", "lin_adobergb_to_lin_rec709",
     "lin_displayp3_to_lin_rec709", "srgb_displayp3_to_lin_rec709"),  # cmlib: matrix colour transforms
    ("standard_surface_to_UsdPreviewSurface", "standard_surface_to_gltf_pbr", "standard_surface_to_open_pbr_surface",
     "open_pbr_surface_to_standard_surface"),
)
ORACLE_CATEGORIES = tuple(c for group in GROUPS for c in group)
# Outputs constant by nature here: the frame of the flat surface (normal +Z, tangent +X, bitangent +Y),
# vertex colours (1), the application's time and frame (constants of the bake).
CONSTANT = ("normal", "tangent", "bitangent", "geomcolor", "time", "frame")
ATOL = RTOL = 1e-5  # see the module docstring


@pytest.mark.slow
@pytest.mark.parametrize("group", range(len(GROUPS)), ids=[g[0] for g in GROUPS])
def test_value_categories_match_materialx_oracle(group):
    # `frame` folds to the conversion's frame (1 by default, the nodedef's default) and `time` to frame / fps;
    # MaterialX's shader reads u_frame and u_time uniforms that the oracle leaves at 0, so the torch side
    # is compiled at frame 0 (time 0).
    require_oracle()
    builder = Builder(seed=100 + group)
    counts = {c: category_nodes(builder, c) for c in GROUPS[group]}
    assert all(counts.values()), f"a category has no drivable nodedef: {counts}"
    uv, pos = points(128, seed=200 + group)
    results = compare(builder, uv, pos, application=Application(frame=0.0))
    spread: dict[str, float] = {}  # per node: the largest variation of its outputs
    for (name, _), (_, want) in results.items():
        spread[name] = max(spread.get(name, 0.0), float(np.ptp(want)))
    flat = [n for n, v in spread.items() if v <= 1e-3 and builder.categories[n] not in CONSTANT]
    assert not flat, f"nodes whose oracle values do not vary (vacuous cases): {flat}"
    assert_within(results, ATOL, RTOL)
