"""MaterialX's compositing nodes compiled to torch (mtlx2neural.graph.compositing), checked against MaterialX's
own generated Slang code at 128 seeded points (the per-point node oracle, mtlx2neural.oracle.points).

Every nodedef of every category (float, color3 and color4 where MaterialX defines them) is a node whose
inputs (fg, bg, mix, in, mask) each follow their own smooth function of uv (in [-3, 3]^2) and position,
sweeping [0.1, 0.9] (tests/node_oracle.py): so alphas sum to both below and above 1 (disjointover's two
branches), and burn/dodge/unpremult divide by values away from zero.

Tolerance: |torch - MaterialX| <= 1e-6 + 1e-6 |MaterialX|.  Both sides evaluate the same float32 expressions
in the same order, but the sine drivers (torch's and the shader's sin may differ in the last bit) feed the
divisions of burn, dodge and unpremult, which amplify that bit where the divisor is small (values up to 9):
measured max 2.1e-6 absolute there, 1.2e-7 elsewhere.
"""

from __future__ import annotations

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

ORACLE_CATEGORIES = ("over", "screen", "burn", "dodge", "mask", "matte", "inside", "outside", "disjointover",
                     "in", "out", "premult", "unpremult", "plus", "minus", "difference")
PARTS = 3  # burn and dodge: one nodedef per shader (see node_oracle.category_nodes)
ATOL = RTOL = 1e-6  # see the module docstring


@pytest.mark.slow
@pytest.mark.parametrize("part", range(PARTS))
def test_compositing_matches_materialx_oracle(part):
    require_oracle()
    builder = Builder(seed=40 + part)
    counts = {c: category_nodes(builder, c, part=part, parts=PARTS) for c in ORACLE_CATEGORIES}
    if part == 0:
        assert all(counts.values()), f"a category has no drivable nodedef: {counts}"
    uv, pos = points(128, seed=50 + part)
    results = compare(builder, uv, pos)
    for key, (_, want) in results.items():
        assert float(want.max() - want.min()) > 0.1, f"{key}: the oracle's values hardly vary (vacuous test)"
    assert_within(results, ATOL, RTOL)


def test_every_compositing_category_has_a_nodedef():
    """Every category listed above exists in MaterialX's stdlib, and every nodedef is drivable."""
    lib = standard_library()
    for c in ORACLE_CATEGORIES:
        assert nodedefs(c) and len(nodedefs(c)) == len(lib.getMatchingNodeDefs(c)), c
