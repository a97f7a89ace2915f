"""UDIM materials in training (mtlx2neural.train.udim, scene.udim_tiles): the touched tiles are
trained, each with its own latents, and the untouched tile on disk is not."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from udim_sample import COLOURS, PLANE, udim_reference, write_plane_stage

from mtlx2neural.contract import ShadingPoint
from mtlx2neural.model.checkpoint import load_checkpoint
from mtlx2neural.scene.udim_tiles import touched_tiles, triangle_tiles
from mtlx2neural.train.config import preset
from mtlx2neural.train.trainer import Trainer
from mtlx2neural.train.udim import (
    TiledStack,
    build_tiled_stack,
    build_training_stack,
    draw_uv,
    tiles_on_disk,
    training_tiles,
    udim_patterns,
)

pytest.importorskip("pxr", reason="the plane's UVs are read from a USD stage")


def test_triangle_tiles_needs_positive_area():
    # The plane's two triangles over [0,2]x[0,1] meet tile 1011 only along v = 1: not touched.
    quad = np.array([[[0, 0], [2, 0], [2, 1]], [[0, 0], [2, 1], [0, 1]]], dtype=float)
    assert triangle_tiles(quad) == ([1001, 1002], 0)
    # A triangle across the corner (1, 1) whose hypotenuse passes below it misses tile 1012.
    assert triangle_tiles(np.array([[[0.9, 0.9], [1.05, 0.9], [0.9, 1.05]]])) == ([1001, 1002, 1011], 0)
    # Degenerate triangles touch nothing; u < 0 is outside every tile and counted.
    assert triangle_tiles(np.array([[[0.5, 0.5], [0.5, 0.5], [0.7, 0.7]]])) == ([], 0)
    assert triangle_tiles(np.array([[[-0.5, 0.2], [0.5, 0.2], [0.5, 0.8]]])) == ([1001], 1)


def test_draw_uv_covers_the_tiles_uniformly():
    uv = draw_uv(20000, [1001, 1002, 1011], torch.Generator().manual_seed(0))
    tiles = (1001 + uv[:, 0].floor() + 10 * uv[:, 1].floor()).long()
    counts = torch.stack([(tiles == t).sum() for t in (1001, 1002, 1011)]).float()
    # 20000 draws, 1/3 each: binomial sd ~67, so 5 sd of slack is 330.
    assert set(tiles.tolist()) == {1001, 1002, 1011} and (counts - 20000 / 3).abs().max() < 330


def test_udim_training_learns_each_touched_tile(tmp_path):  # ~5 s on 2 shared cores
    ref = udim_reference(tmp_path / "tex")
    assert [p for _, p in udim_patterns(ref.compiled)] == [str(tmp_path / "tex" / "base.<UDIM>.exr")]
    assert tiles_on_disk(ref.compiled) == [1001, 1002, 1011]
    from mtlx2neural.scene.usd_stage import open_stage

    tiles, notes = touched_tiles(open_stage(str(write_plane_stage(tmp_path / "plane.usda"))), [PLANE])
    assert tiles == [1001, 1002] and notes == []  # 1011 is on disk, but the plane never reaches it
    stack = build_tiled_stack(ref.compiled, tiles)
    assert stack.resolution == (8, 8) and len(stack.stacks) == 2
    cfg = preset("fast", iterations=100, batch=256, seed=0, decoder="2x16")
    tr = Trainer(ref, stack, cfg, tmp_path / "out")
    model = tr.run(progress=False)
    assert model.latents.tile_list == [1001, 1002] and model.latents.levels[0].shape[:2] == (2, 8)
    wi = torch.tensor([[0.0, 0.0, 1.0]]).expand(4, 3)
    wo = torch.nn.functional.normalize(torch.tensor([[0.3, 0.2, 1.0]]), dim=-1).expand(4, 3)
    uv = torch.tensor([[0.3, 0.4], [0.7, 0.8], [1.3, 0.4], [1.7, 0.8]])
    got = model.eval(wi, wo, uv).detach()
    want = ref.eval(wi, wo, ShadingPoint(uv=uv))
    # The two tiles differ as the reference does: red in 1001, blue in 1002.
    assert COLOURS[1001][0] > COLOURS[1001][2] and bool((got[:2, 0] > 4 * got[:2, 2]).all()), got
    assert bool((got[2:, 2] > 4 * got[2:, 0]).all()), got
    # 100 steps of a 2x16 decoder: measured max |error| 0.009, 0.005, 0.005 (seeds 0, 1, 2) against the
    # 0.24 peak channel; 0.02 leaves room for platform differences, and is far below the 0.2 tile contrast.
    assert float((got - want).abs().max()) < 0.02, (got, want)
    with pytest.raises(ValueError, match="UDIM tile 1011"):
        model.eval(wi[:1], wo[:1], torch.tensor([[0.5, 1.5]]))
    # The checkpoint records the tiles and loads back as the same UDIM model.
    assert torch.load(tr.checkpoint_path, weights_only=False)["udim_tiles"] == [1001, 1002]
    again = load_checkpoint(tr.checkpoint_path)
    assert again.latents.tile_list == [1001, 1002]
    assert torch.equal(again.eval(wi, wo, uv), model.eval(wi, wo, uv).detach())


def test_training_tiles_from_meshes_or_disk(tmp_path):
    """With a stage and bound meshes the touched tiles; without (.mtlx input) every tile on disk;
    a material without a UDIM set: None (one periodic pyramid)."""
    import MaterialX as mx

    from mtlx2neural.graph import compile_material

    ref = udim_reference(tmp_path / "tex")
    stage = write_plane_stage(tmp_path / "plane.usda")
    assert training_tiles(ref.compiled, str(stage), [PLANE]) == ([1001, 1002], [])
    assert training_tiles(ref.compiled) == ([1001, 1002, 1011], [])
    tiles, notes = training_tiles(ref.compiled, str(stage), ["/World/Nothing"])
    assert tiles == [1001, 1002, 1011] and "no such prim" in notes[0] and "every tile on disk" in notes[-1]
    stack, notes = build_training_stack(ref.compiled, str(stage), [PLANE], resolution=(4, 4))
    assert isinstance(stack, TiledStack) and stack.tiles == [1001, 1002] and stack.resolution == (4, 4)
    doc = mx.createDocument()
    doc.addMaterialNode("Plain", doc.addNode("standard_surface", "s", "surfaceshader"))
    plain = compile_material(doc, "Plain")
    assert training_tiles(plain, str(stage), [PLANE]) == (None, [])
    assert not isinstance(build_training_stack(plain, resolution=(1, 1))[0], TiledStack)
