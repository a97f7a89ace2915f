"""The UDIM latent pyramid (mtlx2neural.model.latent): one [C, H, W] pyramid per tile, tile lookup
by uv, clamp addressing inside a tile, and the plain pyramid as the untiled case."""

from __future__ import annotations

import pytest
import torch

from mtlx2neural.imaging.grid_lookup import bilinear_periodic
from mtlx2neural.model.checkpoint import model_arguments
from mtlx2neural.model.latent import LatentPyramid, bilinear_clamp
from mtlx2neural.model.neural_material import NeuralMaterial


def _pyramid(tiles, seed=0):
    torch.manual_seed(seed)
    return LatentPyramid(4, 6, channels=3, init_std=1.0, tiles=tiles)


def test_each_tile_reads_its_own_grid_at_frac_uv():
    lat = _pyramid([1011, 1001, 1002])  # sorted on construction
    assert lat.tile_list == [1001, 1002, 1011] and lat.levels[0].shape == (3, 3, 4, 6)
    g = torch.Generator().manual_seed(1)
    local = torch.rand(64, 2, generator=g) * 0.8 + 0.1
    for t, (tu, tv) in enumerate(((0, 0), (1, 0), (0, 1))):
        for k in range(lat.num_levels):
            uv = local + torch.tensor([float(tu), float(tv)])
            got = lat.fetch(uv, torch.full((64,), k))
            # frac(local + tile) differs from local by float32 rounding (~1e-7 of uv): 1e-5 of a unit-sized code.
            assert torch.allclose(got, bilinear_clamp(lat.levels[k][t], local), atol=1e-5), (t, k)


def test_clamp_at_tile_edges_not_wrap():
    lat = _pyramid([1001, 1002])
    grid = lat.levels[0][0]
    # At u -> 1 inside tile 1001 the last column is read, not a blend with the first (wrap).
    got = lat.fetch(torch.tensor([[0.99999, 0.5]]), torch.zeros(1, dtype=torch.long))
    wrap = bilinear_periodic(grid, torch.tensor([[0.99999, 0.5]]))
    right = bilinear_clamp(grid, torch.tensor([[1.0, 0.5]]))
    assert torch.allclose(got, right, atol=1e-4) and not torch.allclose(got, wrap, atol=1e-2)


def test_untrained_tile_is_a_clear_error():
    lat = _pyramid([1001, 1002])
    with pytest.raises(ValueError, match=r"UDIM tile 1011, which this material was not trained on.*1001, 1002"):
        lat.fetch(torch.tensor([[0.5, 0.5], [0.5, 1.5]]), torch.zeros(2, dtype=torch.long))
    with pytest.raises(ValueError, match="no UDIM tile"):
        lat.fetch(torch.tensor([[-0.5, 0.5]]), torch.zeros(1, dtype=torch.long))
    with pytest.raises(ValueError, match="distinct"):
        LatentPyramid(2, 2, tiles=[1001, 1001])


def test_untiled_pyramid_unchanged():
    """Without tiles the state dict and shapes are those of every existing checkpoint."""
    lat = LatentPyramid(4, 6, channels=3)
    assert lat.tile_list is None and lat.levels[0].shape == (3, 4, 6)
    assert "tiles" not in lat.state_dict() and lat.resolution == (4, 6)


def test_tiles_survive_the_state_dict():
    m = NeuralMaterial((4, 6), in_dim=3, tiles=[1002, 1001])
    state = m.state_dict()
    assert state["latents.tiles"].tolist() == [1001, 1002]
    args = model_arguments(state, {})
    assert args["tiles"] == [1001, 1002] and args["resolution"] == (4, 6) and args["latent_dim"] == 8
    again = NeuralMaterial(**args)
    again.load_state_dict(state)
    assert again.describe()["udim_tiles"] == [1001, 1002] and again.describe()["resolution"] == [4, 6]
    assert model_arguments(NeuralMaterial((4, 6), in_dim=3).state_dict(), {})["tiles"] is None
