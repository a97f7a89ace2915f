"""imaging/udim.py owns UDIM tile numbering: point, batch and tile-list forms agree."""

import math

import pytest
import torch

from mtlx2neural.imaging.udim import (
    check_tiles,
    tile_of_udim,
    udim_at,
    udim_number,
    udim_of_uv,
)

POINTS = [(0.5, 0.5), (1.0, 0.0), (9.99, 0.2), (0.2, 1.0), (-0.1, 0.5), (10.0, 0.5), (0.5, -0.01),
          (math.nan, 0.5), (3.0, 7.5)]
EXPECTED = [1001, 1002, 1010, 1011, -1, -1, -1, -1, 1074]


def test_udim_of_points_and_batches_agree():
    assert udim_of_uv(torch.tensor(POINTS)).tolist() == EXPECTED
    assert [udim_at(u, v) or -1 for u, v in POINTS] == EXPECTED


def test_numbering_round_trips():
    for tu in range(10):
        for tv in range(4):
            assert tile_of_udim(udim_number(tu, tv)) == (tu, tv)
            assert udim_at(tu + 0.5, tv + 0.5) == udim_number(tu, tv)


def test_check_tiles_sorts_and_refuses_bad_lists():
    assert check_tiles([1011, 1001]) == [1001, 1011]
    for bad in ([], [1000], [1001, 1001]):
        with pytest.raises(ValueError, match="distinct numbers >= 1001"):
            check_tiles(bad)
