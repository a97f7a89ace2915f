"""UDIM latents through export and load_neural: one latent EXR per channel group and tile,
``<UDIM>`` asset paths in the layer, the tile list in the manifest and the layer, and a missing
tile named."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch
from conftest import SIMPLE_MTLX
from neural_models import randomise_latents

import mtlx2neural as m2n
from mtlx2neural.contract import ShadingPoint
from mtlx2neural.errors import InputError
from mtlx2neural.export import export_asset
from mtlx2neural.export.latents import (
    read_latent_textures,
    read_mip_chain,
    write_latent_textures,
)
from mtlx2neural.material_record import MaterialRecord
from mtlx2neural.model.neural_material import NeuralMaterial

pytest.importorskip("pxr", reason="the layer is USD")
pytest.importorskip("OpenImageIO", reason="latents are OpenEXR files")
TILES = [1001, 1002]


def udim_model(seed=0) -> NeuralMaterial:
    """A (5, 3)-texel, two-tile model with random latents (what training leaves, for the files)."""
    torch.manual_seed(seed)
    m = NeuralMaterial((5, 3), in_dim=2, latent_dim=6, decoder="2x16", tiles=TILES)
    randomise_latents(m)
    return m.train(False)


def test_latent_files_per_tile(tmp_path):
    model = udim_model()
    paths, _ = write_latent_textures(list(model.latents.levels), tmp_path, tiles=TILES)
    assert [p.name for p in paths] == ["latents_0.<UDIM>.exr", "latents_1.<UDIM>.exr"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"latents_{k}.{t}.exr" for k in (0, 1) for t in TILES]
    # Each tile's file holds that tile's pyramid: channels 0-3 of tile 1002, level 0, as half.
    chain = read_mip_chain(tmp_path / "latents_0.1002.exr")
    want = model.latents.levels[0][1, :4].detach().permute(1, 2, 0).half().numpy()
    assert len(chain) == model.latents.num_levels and np.array_equal(chain[0], want)
    back = read_latent_textures(paths, 6, TILES)
    assert all(torch.equal(b, lv.detach().half().float()) for b, lv in zip(back, model.latents.levels))


def _export(model, tmp_path):
    asset = tmp_path / "thing.mtlx"
    asset.write_text(SIMPLE_MTLX)
    summary = MaterialRecord("Red", "Red", str(asset), "0" * 64, flip_mean=0.1, steps=1, device="cpu",
                             train_seconds=1.0)
    usda, (m,) = export_asset(asset, [(model, summary, tmp_path / "thing_neural" / "Red")],
                              tmp_path / "thing_neural", "fast")
    return usda, m


def test_export_writes_udim_asset_paths_and_load_neural_round_trips(tmp_path):
    from pxr import Usd, UsdShade

    model = udim_model()
    usda, m = _export(model, tmp_path)
    assert [p.name for p in m.latent_textures] == ["latents_0.<UDIM>.exr", "latents_1.<UDIM>.exr"]
    # The MaterialX node reads every tile from its atlas (tests/codegen/test_materialx_node_udim.py).
    assert m.mtlx_document is not None and m.mtlx_document.is_file()
    assert (m.mtlx_document.parent / "latent_atlas_0.exr").is_file()
    stage = Usd.Stage.Open(str(usda))
    prim = next(p for p in stage.Traverse() if p.GetAttribute("neural:latentTextures"))
    assets = prim.GetAttribute("neural:latentTextures").Get()
    assert all("<UDIM>" in a.path for a in assets) and list(prim.GetAttribute("neural:udimTiles").Get()) == TILES
    shader = next(p for p in stage.Traverse() if p.GetAttribute("inputs:latentTexture0"))
    asset = shader.GetAttribute("inputs:latentTexture0").Get()
    layer = shader.GetAttribute("inputs:latentTexture0").GetPropertyStack()[0].layer
    # USD resolves the pattern per tile, as a renderer's UDIM resolver does.
    tiles = UsdShade.UdimUtils.ResolveUdimTilePaths(UsdShade.UdimUtils.ResolveUdimPath(asset.path, layer), layer)
    assert [(str(p).rsplit("/", 1)[-1], t) for p, t in tiles] == [("latents_0.1001.exr", "1001"),
                                                                  ("latents_0.1002.exr", "1002")]
    loaded = m2n.load_neural(usda, "Red")
    assert loaded.latents.tile_list == TILES
    g = torch.Generator().manual_seed(3)
    uv = torch.rand(512, 2, generator=g) * torch.tensor([2.0, 1.0])  # both tiles
    wi = torch.nn.functional.normalize(torch.rand(512, 3, generator=g) + 0.05, dim=-1)
    wo = torch.nn.functional.normalize(torch.rand(512, 3, generator=g) + 0.05, dim=-1)
    rounded = udim_model()
    with torch.no_grad():
        for p in rounded.parameters():
            p.copy_(p.half().float())
        at = ShadingPoint(uv=uv)
        # The loaded model is the FP16-rounded one: the same float32 arithmetic on the same values.
        torch.testing.assert_close(loaded.eval(wi, wo, at), rounded.eval(wi, wo, at), rtol=1e-6, atol=1e-7)
        # And the tiles are really different textures (not one file read twice).
        assert not torch.allclose(loaded.eval(wi[:1], wo[:1], uv[:1] * 0 + 0.5),
                                  loaded.eval(wi[:1], wo[:1], uv[:1] * 0 + torch.tensor([1.5, 0.5])))
    with pytest.raises(ValueError, match="UDIM tile 1011"):
        loaded.eval(wi[:1], wo[:1], torch.tensor([[0.5, 1.5]]))


def test_missing_tile_file_is_named(tmp_path):
    usda, m = _export(udim_model(), tmp_path)
    gone = m.folder / "latents_1.1002.exr"
    shutil.move(gone, tmp_path / "elsewhere.exr")
    with pytest.raises(InputError, match=r"latents_1\.1002\.exr: the latent texture of UDIM tile 1002"):
        m2n.load_neural(usda, "Red")
