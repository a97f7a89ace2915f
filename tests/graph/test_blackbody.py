"""MaterialX's blackbody node compiled to torch (mtlx2neural.graph.blackbody), checked against MaterialX's own
generated Slang code at 128 seeded points (the per-point node oracle, mtlx2neural.oracle.points).

The temperature follows a smooth function of uv and position over [400, 26000] K, so the points fall
below the 800 K clamp, in each of the three pieces of the chromaticity fit (< 2222 K, < 4000 K, >= 4000 K)
and above the 25000 K clamp; the test checks that each regime holds points.

Tolerance: |torch - MaterialX| <= 1e-6 + 1e-6 |MaterialX|: the same float32 polynomials, the XYZ -> RGB
product summed in another order (last-bit differences), and 1000 / T of a sine-driven T that may differ in
its last bit (measured max 1.4e-6 absolute on channels up to 3.4, ratio 0.35).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from node_oracle import (
    Builder,
    compare,
    max_errors,
    points,
    require_oracle,
)

from mtlx2neural.graph.blackbody import blackbody
from mtlx2neural.graph.library import standard_library

ORACLE_CATEGORIES = ("blackbody",)
ATOL = RTOL = 1e-6  # see the module docstring


@pytest.mark.slow
def test_blackbody_matches_materialx_oracle():
    require_oracle()
    builder = Builder(seed=70)
    kelvin = builder.scalar(400.0, 26000.0)
    builder.target(kelvin, "float")
    builder.node(standard_library().getNodeDef("ND_blackbody"), "bb", sources={"temperature": kelvin})
    uv, pos = points(128, seed=71)
    results = compare(builder, uv, pos)
    t = results[(kelvin, None)][1][:, 0]
    for lo, hi in ((0, 800), (800, 2222), (2222, 4000), (4000, 25000), (25000, 1e9)):
        assert ((t >= lo) & (t < hi)).sum() >= 3, f"too few points in [{lo}, {hi}) K"
    want = results[("bb", None)][1]
    assert float(np.ptp(want)) > 0.5
    errors = max_errors(results, ATOL, RTOL)
    assert errors[("bb", None)] <= 1.0, errors


def test_blackbody_properties():
    t = torch.tensor([[500.0], [800.0], [1500.0], [3000.0], [6500.0], [25000.0], [40000.0]])
    rgb = blackbody(t)
    assert bool((rgb >= 0).all()) and bool(torch.isfinite(rgb).all())
    # Clamped outside [800, 25000] K.
    assert torch.equal(rgb[0], rgb[1]) and torch.equal(rgb[5], rgb[6])
    # Warm to cool from 1500 K up: the red/blue ratio falls with temperature (below, the cubic fit
    # extrapolates from 1000 K and the colour turns back towards blue, as in MaterialX).
    ratio = rgb[2:6, 0] / rgb[2:6, 2].clamp_min(1e-6)
    assert bool((ratio[1:] < ratio[:-1]).all())
    # About D65 white at 6500 K (the sRGB matrix's white point): channels within 10% of each other.
    assert float(rgb[4].max() / rgb[4].min()) < 1.1
