"""MaterialX's ramps and splits compiled to torch (mtlx2neural.graph.ramps: ramplr, ramptb, splitlr, splittb;
ramp4 through its library nodegraph), checked against MaterialX's own generated Slang code at 128 seeded
points (the per-point node oracle, mtlx2neural.oracle.points).

Every nodedef (float, color3, color4, vector2, vector3, vector4) reads the uv spanning [-3, 3]^2, so the
ramps' clamping outside [0, 1] and both sides of every split are exercised; the values and the split's
centre each follow their own smooth function of uv and position in [0.1, 0.9] (tests/node_oracle.py).
A split is a step at a point (MaterialX antialiases it over the screen-space derivative of the
coordinate, which is zero for a point sample); no point lies exactly on a centre.

Tolerance: |torch - MaterialX| <= 1e-6 + 1e-6 |MaterialX|: the same float32 lerp on both sides, fed by
sine drivers that may differ in the last bit between torch and the shader (measured max 1.2e-7).
"""

from __future__ import annotations

import numpy as np
import pytest
from node_oracle import (
    Builder,
    assert_within,
    category_nodes,
    compare,
    nodedefs,
    points,
    require_oracle,
)

from mtlx2neural.graph.library import standard_library

ORACLE_CATEGORIES = ("ramplr", "ramptb", "ramp4", "splitlr", "splittb")
ATOL = RTOL = 1e-6  # see the module docstring


@pytest.mark.slow
def test_ramps_and_splits_match_materialx_oracle():
    require_oracle()
    builder = Builder(seed=60)
    counts = {c: category_nodes(builder, c) for c in ORACLE_CATEGORIES}
    assert all(v == 6 for v in counts.values()), counts  # float, color3/4, vector2/3/4
    uv, pos = points(128, seed=61)
    assert (uv < 0).any() and (uv > 1).any() and ((uv > 0) & (uv < 1)).any()
    results = compare(builder, uv, pos)
    for key, (_, want) in results.items():
        assert float(np.ptp(want)) > 0.1, f"{key}: the oracle's values hardly vary (vacuous test)"
    assert_within(results, ATOL, RTOL)


def test_every_ramp_nodedef_is_drivable():
    lib = standard_library()
    for c in ORACLE_CATEGORIES:
        assert len(nodedefs(c)) == len(lib.getMatchingNodeDefs(c)) == 6, c
