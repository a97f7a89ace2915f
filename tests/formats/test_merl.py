"""The MERL file: layout, scale factors, errors, and the half/difference indexing against an independent
scalar transcription of the format's reference reader (plain ``math``, one pair at a time)."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
import torch
from conftest import random_dirs
from merl_samples import ggx_plastic

from mtlx2neural.errors import InputError
from mtlx2neural.formats.merl import (
    MERL_DIMS,
    SCALE,
    continuous_index,
    directions_of,
    half_difference_angles,
    node_angles,
    read_merl,
    tabulate,
    write_merl,
)

SMALL = (6, 5, 8)


def _reference_index(wi, wo, dims=MERL_DIMS) -> int:
    """The format's reference reader, step by step in scalar float64: half vector, rotate the light
    direction by -phi_h about the normal and -theta_h about the binormal, truncate the three indices."""

    def rotate(v, axis, angle):
        c, s = math.cos(angle), math.sin(angle)
        d = sum(a * b for a, b in zip(axis, v))
        cr = (axis[1] * v[2] - axis[2] * v[1], axis[2] * v[0] - axis[0] * v[2], axis[0] * v[1] - axis[1] * v[0])
        return tuple(v[i] * c + axis[i] * d * (1 - c) + cr[i] * s for i in range(3))

    h = [a + b for a, b in zip(wi, wo)]
    n = math.sqrt(sum(x * x for x in h))
    h = [x / n for x in h]
    theta_h, phi_h = math.acos(max(-1.0, min(1.0, h[2]))), math.atan2(h[1], h[0])
    d = rotate(rotate(wo, (0.0, 0.0, 1.0), -phi_h), (0.0, 1.0, 0.0), -theta_h)
    theta_d, phi_d = math.acos(max(-1.0, min(1.0, d[2]))), math.atan2(d[1], d[0])
    ih = 0 if theta_h <= 0 else min(dims[0] - 1, int(math.sqrt(theta_h / (math.pi / 2) * dims[0] * dims[0])))
    idd = max(0, min(dims[1] - 1, int(theta_d / (math.pi / 2) * dims[1])))
    if phi_d < 0:
        phi_d += math.pi
    ip = max(0, min(dims[2] - 1, int(phi_d / math.pi * dims[2])))
    return (ih * dims[1] + idd) * dims[2] + ip


def test_indices_match_the_reference_reader():
    # 2000 random pairs in float64. The transcription uses acos where the module uses atan2, so the two
    # truncated indices may differ only when a continuous index lies within 1e-6 of an integer: such
    # pairs are skipped (none expected at this count), everything else must agree exactly.
    wi, wo = random_dirs(2000, seed=1).double(), random_dirs(2000, seed=2).double()
    ih, idd, ip = continuous_index(*half_difference_angles(wi, wo))
    ours = ((ih.floor().clamp(0, 89) * 90 + idd.floor().clamp(0, 89)) * 180 + ip.floor().clamp(0, 179)).long()
    near = torch.stack([(x - x.round()).abs() < 1e-6 for x in (ih, idd, ip)]).any(0)
    expected = torch.tensor([_reference_index(a.tolist(), b.tolist()) for a, b in zip(wi, wo)])
    assert int(near.sum()) < 5
    assert torch.equal(ours[~near], expected[~near])


def test_directions_of_inverts_the_angles():
    th, td, pd = (torch.as_tensor(a) for a in node_angles(SMALL))
    grid = torch.stack(torch.meshgrid(th, td, pd, indexing="ij"), 0).reshape(3, -1)
    wi, wo = directions_of(*grid)
    back = half_difference_angles(wi, wo)
    # float64 round trip through trigonometry: 1e-9 rad. phi_d is compared on the fold (mod pi), and is
    # undefined where theta_d = 0 (the difference vector is the pole).
    torch.testing.assert_close(back[0], grid[0], atol=1e-9, rtol=0)
    torch.testing.assert_close(back[1], grid[1], atol=1e-9, rtol=0)
    defined = grid[1] > 1e-6
    dphi = torch.remainder(back[2] - grid[2] + 0.5 * math.pi, math.pi) - 0.5 * math.pi
    assert float(dphi[defined].abs().max()) < 1e-9


def test_file_layout_and_scale_factors(tmp_path):
    rgb = np.random.default_rng(3).uniform(0.0, 2.0, size=(3, *SMALL))
    rgb[:, 0, 0, 0] = -1.0  # unmeasured
    path = write_merl(tmp_path / "t.binary", rgb)
    data = path.read_bytes()
    assert struct.unpack("<3i", data[:12]) == SMALL
    assert len(data) == 12 + 3 * math.prod(SMALL) * 8
    stored = np.frombuffer(data[12:], dtype="<f8").reshape(3, *SMALL)
    # channel-major, phi_d fastest: the value of red at (theta_h 1, theta_d 2, phi_d 3)
    assert stored[0, 1, 2, 3] == rgb[0, 1, 2, 3] / SCALE[0]
    assert data[12 + 8 * ((1 * SMALL[1] + 2) * SMALL[2] + 3):][:8] == struct.pack("<d", stored[0, 1, 2, 3])
    table = read_merl(path)
    # stored / scale * scale: float64 rounding of two operations
    np.testing.assert_allclose(table.rgb, rgb, rtol=4e-16, atol=0)
    assert table.dims == SMALL and int(table.missing.sum()) == 1


def test_tabulate_stores_the_brdf_at_the_nodes():
    brdf = ggx_plastic()
    table = tabulate(brdf, SMALL)
    th, td, pd = node_angles(SMALL)
    wi, wo = directions_of([th[3]], [td[2]], [pd[5]])
    assert table[:, 3, 2, 5] == pytest.approx(brdf(wi, wo)[0].numpy(), rel=1e-12)
    below = table[:, :, -1, :] < 0  # theta_d = 72 degrees with theta_h up to 64: some below the horizon
    assert below.any() and (table >= 0).any()


@pytest.mark.parametrize("damage", ["truncated", "header", "nan", "empty"])
def test_malformed_files_name_the_file_and_are_not_touched(tmp_path, damage):
    path = write_merl(tmp_path / "m.binary", np.ones((3, *SMALL)))
    data = bytearray(path.read_bytes())
    if damage == "truncated":
        data = data[:-8]
    elif damage == "header":
        data[:12] = struct.pack("<3i", 90, 90, 180)
    elif damage == "nan":
        data[20:28] = struct.pack("<d", float("nan"))
    else:
        data = data[:4]
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match="m.binary"):
        read_merl(path)
    assert path.read_bytes() == bytes(data)


def test_missing_file_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="nothing.binary"):
        read_merl(tmp_path / "nothing.binary")
