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
