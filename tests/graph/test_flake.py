"""MaterialX's flake2d/flake3d compiled to torch (mtlx2neural.graph.flake), checked against MaterialX's own
generated Slang code at 256 seeded points (the per-point node oracle, mtlx2neural.oracle.points).

Points: uv in [-3, 3]^2 and positions in [-3, 3]^3, so negative cell coordinates and many cells occur.
Each node has constant size, roughness and coverage (several sets: small and large flakes, sparse to full
coverage; constants so that the cell a point falls in is not moved by the last bit of a driver's sine),
and either MaterialX's default frame (Nworld, Tworld, Bworld: +Z, +X, +Y on both sides) or a normal,
tangent and bitangent that follow smooth functions of uv and position (tests/node_oracle.py), not unit
and not orthogonal, so that the flake normal's formula is checked channel by channel.  Every output is
compared: id, rand, presence and flakenormal.

Tolerance: |torch - MaterialX| <= 1e-5 + 1e-5 |MaterialX|.  The hashes are the same 32-bit integer
arithmetic, so which flake covers a point agrees exactly (id, rand and presence are equal at these seeds);
the flake normal goes through sin, cos, sqrt and a normalisation of the driven (sine) frame vectors, whose
last bits differ (measured max 1.9e-6 absolute, 0.18 of the tolerance); ``id`` is up to 2^24, where one
unit is 6e-8 relative (a last-bit difference of ``rand`` could move it by one).  A point within a float32
rounding of a cell or cube boundary could pick another flake; at these seeds none does.

MaterialX 1.39.5's Slang generator emits the flake library's GLSL unchanged, which does not compile as
Slang; the oracle patches it to the GLSL meaning (mtlx2neural.oracle.source._patch_flake).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from node_oracle import Builder, assert_within, compare, points, require_oracle

from mtlx2neural.graph.flake import (
    cell_noise3_w,
    cell_noise_w,
    coverage_probability,
    flake,
    rotate_flake,
)
from mtlx2neural.graph.library import standard_library

ORACLE_CATEGORIES = ("flake2d", "flake3d")
ATOL = RTOL = 1e-5  # see the module docstring
# (size, roughness, coverage): MaterialX's defaults scaled to the point spans, sparse to full coverage.
PARAMETERS = ((0.15, 0.1, 0.5), (0.4, 0.6, 0.25), (0.08, 0.9, 1.0), (0.25, 0.3, 0.05))


@pytest.mark.slow
def test_flakes_match_materialx_oracle():
    require_oracle()
    lib = standard_library()
    builder = Builder(seed=60)
    for category in ORACLE_CATEGORIES:
        nd = lib.getNodeDef(f"ND_{category}")
        for k, (size, rough, cover) in enumerate(PARAMETERS):
            values = {"size": size, "roughness": rough, "coverage": cover}
            if k % 2 == 0:  # MaterialX's default frame (the geometric properties)
                skip = {"normal": "", "tangent": "", "bitangent": ""}
                builder.node(nd, f"{category}_{k}", values=values, sources=None)
                _drop_inputs(builder, f"{category}_{k}", skip)
            else:  # driven frame vectors
                builder.node(nd, f"{category}_{k}", values=values)
    uv, pos = points(256, seed=61)
    results = compare(builder, uv, pos)
    for (name, out), (_, want) in results.items():
        if out in ("id", "rand", "presence"):
            covered = float((want[:, 0] > 0).mean())
            assert 0.0 < covered < 1.0 or name.endswith("_2"), f"{name}.{out}: covers {covered} of the points"
            assert float(np.ptp(want)) > 0.1, f"{name}.{out}: hardly varies (vacuous test)"
    assert_within(results, ATOL, RTOL)


def _drop_inputs(builder: Builder, name: str, inputs: dict) -> None:
    """Remove the connections of ``inputs`` from node ``name``'s XML line, so they keep their defaults."""
    for i, line in enumerate(builder.lines):
        if f'name="{name}"' in line:
            for inp in inputs:
                start = line.find(f'<input name="{inp}"')
                if start >= 0:
                    line = line[:start] + line[line.index("/>", start) + 2:]
            builder.lines[i] = line


def test_flake_outputs_are_consistent():
    """Without a flake every output is 0 and the normal passes through; with one, id = int(rand (2^24 - 1)),
    presence is in (0, 1] and the flake normal is a unit vector about the normal."""
    g = torch.Generator().manual_seed(5)
    pos = torch.rand(1024, 3, generator=g) * 8 - 4
    one = torch.ones(1, 1)
    normal, tangent, bitangent = torch.tensor([[0.0, 0.0, 1.0]]), torch.tensor([[1.0, 0.0, 0.0]]), \
        torch.tensor([[0.0, 1.0, 0.0]])
    out = flake(0.2 * one, 0.3 * one, 0.5 * one, pos, normal, tangent, bitangent)
    found = out["presence"][:, 0] > 0
    assert 0.2 < float(found.float().mean()) < 0.95  # coverage 0.5 leaves gaps and covers much
    assert (out["rand"][~found] == 0).all() and (out["id"][~found] == 0).all()
    torch.testing.assert_close(out["flakenormal"][~found], normal.expand(int((~found).sum()), 3))
    torch.testing.assert_close(out["id"][found], torch.trunc(out["rand"][found] * 16777215.0))
    torch.testing.assert_close(out["flakenormal"][found].norm(dim=-1), torch.ones(int(found.sum())))
    cos_n = out["flakenormal"][found][:, 2]
    # GGX of width 0.3^2: every flake normal in the upper hemisphere, most near the normal (a long tail).
    assert (cos_n >= 0).all() and float(cos_n.median()) > 0.99
    none = flake(0.2 * one, 0.3 * one, 0.0 * one, pos, normal, tangent, bitangent)
    assert (none["presence"] == 0).all()  # coverage 0: no flake at all
    full = flake(0.2 * one, 0.3 * one, one, pos, normal, tangent, bitangent)
    assert float((full["presence"] > 0).float().mean()) > float(found.float().mean())


def test_flake_helpers():
    # The coverage curve: 0 at 0, increasing, above 0.9 at full coverage (the cubes overlap: most points covered).
    x = torch.linspace(0, 1, 11)
    p = coverage_probability(x)
    assert float(p[0]) == 0.0 and (p[1:] > p[:-1]).all() and float(p[-1]) > 0.9
    # Arvo's rotation keeps lengths.
    g = torch.Generator().manual_seed(6)
    v, r = torch.randn(64, 3, generator=g), torch.rand(64, 3, generator=g)
    torch.testing.assert_close(rotate_flake(v, r).norm(dim=-1), v.norm(dim=-1), atol=1e-5, rtol=0)
    # The 4D cell noises are deterministic, in [0, 1), and depend on the fourth coordinate.
    cells = torch.floor(torch.randn(64, 3, generator=g) * 5)
    a, b = cell_noise_w(cells, 3.0), cell_noise_w(cells, 2.0)
    assert ((a >= 0) & (a < 1)).all() and not torch.equal(a, b)
    assert torch.equal(cell_noise3_w(cells, 2.0), cell_noise3_w(cells + 0.5, 2.0))  # floor of the cell
