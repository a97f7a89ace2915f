"""The analytic baseline of a UDIM material (the layer's UsdPreviewSurface fallback): fitted on a tiled
stack it holds one map per trained tile, each tile's base colour is its texture's, it saves and loads
with its tiles, and its preview textures are one file per tile behind a ``<UDIM>`` pattern. The
two-tile diffuse material of tests/udim_sample.py (1001 red, 1002 blue; 1011 on disk, not fitted)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from udim_sample import COLOURS, udim_reference

from mtlx2neural.baseline.analytic_model import (
    fit_analytic,
    load_analytic,
    save_analytic,
    write_preview_textures,
)
from mtlx2neural.train.udim import build_tiled_stack

TILES = [1001, 1002]


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    torch.set_num_threads(1)
    ref = udim_reference(tmp_path_factory.mktemp("udim_tiles"))
    stack = build_tiled_stack(ref.compiled, TILES)
    return ref, fit_analytic(ref, stack, iterations=60, batch=512, seed=0)


def test_a_tiled_stack_fits_one_map_per_tile_with_its_colour(fitted):
    _, model = fitted
    assert model.tiles == TILES and model.maps.levels[0].shape[:2] == (2, 8)
    for k, tile in enumerate(TILES):
        base = model.level_maps(0, k)["base"].reshape(-1, 3).mean(0)
        # 0.05: a constant diffuse tile (specular 0): the fit's initial guess is the reference's
        # off-specular response, and 60 Adam steps keep it; another tile's colour is >= 0.75 away.
        assert np.abs(base - np.array(COLOURS[tile])).max() < 0.05, (tile, base)
    wi = torch.tensor([[0.0, 0.0, 1.0]])
    with pytest.raises(ValueError, match="UDIM tile 1011"):  # never fitted, as the neural model
        model.eval(wi, wi, torch.tensor([[0.5, 1.5]]))


def test_save_load_and_preview_textures_per_tile(fitted, tmp_path):
    import OpenImageIO as oiio

    _, model = fitted
    loaded = load_analytic(save_analytic(model, tmp_path / "analytic.pt"))
    assert loaded.tiles == TILES
    for a, b in zip(loaded.maps.levels, model.maps.levels):
        assert torch.equal(a, b.detach())
    baked = write_preview_textures(loaded, tmp_path / "preview")
    assert baked["textures"]["diffuseColor"].name == "diffuseColor.<UDIM>.exr"
    for k, tile in enumerate(TILES):
        img = oiio.ImageBuf(str(tmp_path / "preview" / f"diffuseColor.{tile}.exr")).get_pixels(oiio.FLOAT)
        # half-float files of the fitted maps: FP16 rounding, 1e-3 relative
        assert np.allclose(img[..., :3], loaded.level_maps(0, k)["base"], rtol=1e-3, atol=1e-4)
    assert not (tmp_path / "preview" / "diffuseColor.exr").exists()
