"""render.udim_view: a UDIM model rendered through TileView reads only its tile, wrapped into it (the
sphere's seam and poles at u = 1 / v = 1 and the plane's [0, 2]^2 included), ClampToTiles keeps edge uv inside the trained tiles, and
compare_tiles renders the views once per tile. Seeded random two-tile models; no training."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from neural_models import randomise_latents

from mtlx2neural.contract import ShadingPoint
from mtlx2neural.model.neural_material import NeuralMaterial
from mtlx2neural.render.renderer import View, render
from mtlx2neural.render.udim_view import (
    EDGE,
    ClampToTiles,
    TileView,
    compare_tiles,
    model_tiles,
)

TILES = [1002, 1011]  # no 1001: the sphere's own uv would raise


def udim_model(seed: int = 0) -> NeuralMaterial:
    torch.manual_seed(seed)
    m = NeuralMaterial((4, 4), in_dim=2, latent_dim=6, decoder="2x16", tiles=TILES)
    randomise_latents(m)
    return m.train(False)


def _dirs(n: int):
    wi = torch.tensor([[0.0, 0.0, 1.0]]).expand(n, 3)
    wo = torch.tensor([[0.6, 0.0, 0.8]]).expand(n, 3)
    return wi, wo


def test_tile_view_wraps_uv_into_its_tile():
    model = udim_model()
    assert model_tiles(model) == TILES and model_tiles(object()) is None
    local = torch.tensor([[0.25, 0.5], [0.0, 0.0], [1.0, 1.0], [0.999, 0.3]])
    wi, wo = _dirs(len(local))
    with pytest.raises(ValueError, match="UDIM tile 1001"):
        model.eval(wi, wo, local)
    for tile, origin in ((1002, (1.0, 0.0)), (1011, (0.0, 1.0))):
        view = TileView(model, tile)
        got = view.eval(wi, wo, ShadingPoint(uv=local))
        # wrapped into the tile: (1, 1) reads the tile's (0, 0), as a repeated texture would
        want = model.eval(wi, wo, torch.tensor([[0.25, 0.5], [0.0, 0.0], [0.0, 0.0], [0.999, 0.3]]) + torch.tensor(origin))
        # the same latents read at the same uv: bit-identical
        assert torch.equal(got, want)
    # the two tiles hold different random latents, so the views differ
    assert not torch.allclose(TileView(model, 1002).eval(wi, wo, local), TileView(model, 1011).eval(wi, wo, local))


def test_a_sphere_renders_through_each_tile_view():
    model = udim_model(1)
    with pytest.raises(ValueError, match="UDIM tile 1001"):
        render(model, View(0.0, 15.0), res=16, spp=1, texels=(4, 4))
    imgs = [render(TileView(model, t), View(0.0, 15.0), res=16, spp=1, texels=(4, 4)) for t in TILES]
    assert all(np.isfinite(i).all() and i.max() > 0 for i in imgs)
    assert np.abs(imgs[0] - imgs[1]).max() > 1e-3  # different tiles, different images


def test_clamp_to_tiles_keeps_trained_uv_and_moves_edge_points_inside():
    model = udim_model(2)
    clamped = ClampToTiles(model, TILES)
    inside = torch.tensor([[1.5, 0.5], [0.25, 1.75]])
    edge = torch.tensor([[2.0, 0.5], [0.5, 2.0], [0.9999999, 1.5]])  # tiles 1003, 1021, 1011's left
    wi, wo = _dirs(len(inside))
    assert torch.equal(clamped.eval(wi, wo, inside), model.eval(wi, wo, inside))
    wi, wo = _dirs(len(edge))
    with pytest.raises(ValueError, match="UDIM tile 1003"):
        model.eval(wi, wo, edge)
    # nearest trained tile, clamped: (2.0, 0.5) -> 1002's right edge; (0.5, 2.0) -> 1011's top;
    # (0.9999999, 1.5) is already in 1011 (u < 1 in float32)
    want = model.eval(wi, wo, torch.tensor([[2.0 - EDGE, 0.5], [0.5, 2.0 - EDGE], [0.9999999, 1.5]]))
    assert torch.allclose(clamped.eval(wi, wo, edge), want, atol=1e-6)


def test_compare_tiles_renders_the_views_once_per_tile():
    model = udim_model(3)
    out = compare_tiles(model, {"neural": model}, (4, 4), TILES, views=(View(0.0, 15.0), View(70.0, 35.0)),
                        res=16, spp=1)
    rows = out["neural"]
    assert [r["tile"] for r in rows] == [1002, 1002, 1011, 1011]
    # the model against itself through the same tile: identical renders, FLIP 0
    assert all(r["flip"] == pytest.approx(0.0, abs=1e-6) for r in rows)
