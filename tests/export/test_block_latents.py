"""Block-compressed latents (``--latent-format bc6h|bc1``): the model reads its latents through the block
decoder's emulation, the export writes DDS MIP chains that decode to exactly those values, and every
consumer (load_neural, the MaterialX node's atlases, an independent BC1 decoder, the Slang runtime's
binding) reads them."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from neural_models import randomise_latents
from test_export import RED_MTLX, _export_red, directions, fake_summary

import mtlx2neural as m2n
from mtlx2neural.contract import ShadingPoint
from mtlx2neural.export import export_asset
from mtlx2neural.formats.dds import read_dds
from mtlx2neural.formats.latent_codec import latent_bytes_per_texel
from mtlx2neural.model.neural_material import NeuralMaterial


def block_model(latent_format: str, resolution=(8, 8), channels=8, seed=0) -> NeuralMaterial:
    """A random 8-channel model whose latents are read through ``latent_format`` (its codec fitted to them)."""
    torch.manual_seed(seed)
    m = NeuralMaterial(resolution, in_dim=2, latent_dim=channels, frames=2, decoder="2x16",
                       latent_format=latent_format)
    randomise_latents(m)
    m.latents.codec.fit(list(m.latents.levels))
    return m.train(False)


@pytest.mark.parametrize("fmt", ["bc6h", "bc1"])
def test_exported_dds_decode_to_the_latents_the_model_reads(tmp_path, fmt):
    """Three DDS files with the whole pyramid as MIP chains; load_neural holds exactly (float32) the values
    the trained model reads through its emulation, so eval agrees up to the FP16 weights' rounding."""
    model = block_model(fmt)
    usda, loaded = _export_red(model, tmp_path)
    folder = next((tmp_path / "thing_neural").rglob("weights.json")).parent
    files = sorted(p.name for p in folder.glob("latents_*"))
    assert files == ["latents_0.dds", "latents_1.dds", "latents_2.dds"]
    dds = read_dds(folder / "latents_0.dds")
    assert (dds.width, dds.height, len(dds.levels)) == (8, 8, 4)
    for k in range(model.latents.num_levels):
        with torch.no_grad():
            torch.testing.assert_close(loaded.latents.levels[k], model.latents.level(k), rtol=0, atol=0)
    wi, wo, _, uv, _ = directions(512, 4)
    at = ShadingPoint(uv=uv, lod=torch.full((512,), 1.3), u_level=torch.rand(512))
    with torch.no_grad():
        # FP16 weights against float32 ones: the round-trip tolerance of test_export.assert_round_trip
        torch.testing.assert_close(loaded.eval(wi, wo, at), model.eval(wi, wo, at), rtol=1e-2, atol=1e-5)


def test_bc1_files_match_an_independent_decoder(tmp_path):
    """texture2ddecoder (a BC1-BC7 decoder this project did not write) reads every exported BC1 level to
    the same 8-bit texels as the loaded latents: t = (latent - offset) / scale, within half an 8-bit step
    plus float rounding of the affine map (1e-4)."""
    t2d = pytest.importorskip("texture2ddecoder", reason="texture2ddecoder (pip) is the independent BC decoder")
    model = block_model("bc1")
    _, loaded = _export_red(model, tmp_path)
    folder = next((tmp_path / "thing_neural").rglob("weights.json")).parent
    off, scale = model.latents.codec.codec_offset, model.latents.codec.codec_scale
    for g in range(3):
        img = read_dds(folder / f"latents_{g}.dds")
        for j, blocks in enumerate(img.levels):
            h = w = max(1, 8 >> j)
            bgra = np.frombuffer(t2d.decode_bc1(blocks, w, h), np.uint8).reshape(h, w, 4)
            theirs = bgra[..., [2, 1, 0]].astype(np.float32) / 255.0
            for c in range(3):
                ch = 3 * g + c
                if ch >= 8:
                    continue
                ours = ((loaded.latents.levels[j][ch].detach() - off[ch]) / scale[ch]).numpy()
                np.testing.assert_allclose(ours, theirs[..., c], atol=1e-4)


@pytest.mark.parametrize("fmt,ratio", [("bc6h", 5), ("bc1", 10)])
def test_block_latents_are_smaller_than_half_float_exr(tmp_path, fmt, ratio):
    """GPU bytes per texel of 8 channels: half-float RGBA x 2 = 16; BC6H 3 x 1 = 3 (5.3x smaller); BC1
    3 x 0.5 = 1.5 (10.7x); and the files on disk (DDS, all levels) are at least that much smaller than
    16 bytes per texel of the pyramid."""
    assert latent_bytes_per_texel("exr", 8) == 16.0
    assert latent_bytes_per_texel(fmt, 8) * ratio <= 16.0
    model = block_model(fmt, resolution=(128, 128))
    _export_red(model, tmp_path)
    folder = next((tmp_path / "thing_neural").rglob("weights.json")).parent
    on_disk = sum(p.stat().st_size for p in folder.glob("latents_*.dds"))
    texels = sum(lv.shape[-1] * lv.shape[-2] for lv in model.latents.levels)
    assert on_disk * ratio <= 16 * texels * 1.05  # + the DDS headers (148 bytes per file)


def test_materialx_node_atlases_hold_the_decoded_latents(tmp_path):
    """The MaterialX node's latent atlases (half RGBA) are filled from the DDS files: BC6H texels are halves,
    so the atlas holds them exactly."""
    from mtlx2neural.codegen.materialx_node import latent_atlas, read_latent_files
    from mtlx2neural.formats.latent_codec import codec_of

    model = block_model("bc6h")
    _export_red(model, tmp_path)
    folder = next((tmp_path / "thing_neural").rglob("weights.json")).parent
    assert list((folder / "materialx").glob("latent_atlas_*.exr"))
    codec = codec_of(folder)
    assert codec is not None and codec.format.name == "bc6h"
    layout, chains = read_latent_files(sorted(folder.glob("latents_*.dds")), 8, codec=codec)
    assert layout.groups == 2 and len(chains[0]) == model.latents.num_levels
    with torch.no_grad():
        want = model.latents.level(0)[:4].permute(1, 2, 0).numpy()
    np.testing.assert_array_equal(chains[0][0].astype(np.float32), want)
    assert latent_atlas(chains[0]).dtype == np.float16


def test_the_slang_module_names_its_block_textures(tmp_path):
    """The generated Slang module says which files hold the latents and which runtime source binds them."""
    from mtlx2neural.codegen.generate import generate_slang

    text = generate_slang(block_model("bc1"), "Red")
    line = next(ln for ln in text.splitlines() if ln.startswith("// Latent textures:"))
    assert "latents_<k>.dds" in line and "BC1" in line and "NMBlockTextureLatents8" in line and "offset {" in line
    assert "latents_<k>.exr" in next(ln for ln in generate_slang(block_model_exr(), "Red").splitlines()
                                     if ln.startswith("// Latent textures:"))


def block_model_exr() -> NeuralMaterial:
    torch.manual_seed(0)
    return NeuralMaterial((8, 8), in_dim=2, latent_dim=8, frames=2, decoder="2x16").train(False)


def test_the_slang_runtime_binds_block_textures(tmp_path):
    """NMBlockTextureLatents8 (three BC textures, per-channel offset and scale) compiles with slangc and
    feeds nmFetchLatent."""
    from mtlx2neural.codegen.compile import find_slangc, slangc
    from mtlx2neural.codegen.paths import runtime_path

    if find_slangc() is None:
        pytest.skip("slangc not found (pip install --no-deps slangtorch)")
    probe = tmp_path / "probe.slang"
    probe.write_text("""import NeuralMaterial;
Texture2D<float4> g0; Texture2D<float4> g1; Texture2D<float4> g2; SamplerState s;
RWStructuredBuffer<float> gOut;
[shader("compute")][numthreads(1, 1, 1)]
void main(uint3 id : SV_DispatchThreadID)
{
    NMBlockTextureLatents8 lat;
    lat.group0 = g0; lat.group1 = g1; lat.group2 = g2; lat.bilinearWrap = s; lat.numLevels = 9;
    for (int k = 0; k < 8; k++) { lat.offset[k] = 0.5; lat.scale[k] = 2.0; }
    NMLatent<8> l = nmFetchLatent(lat, float2(0.3, 0.4), 1.5, 0.2);
    gOut[0] = l.v[0] + l.v[7];
}
""")
    assert runtime_path().is_dir()
    hlsl = slangc(probe, "hlsl", entry="main", stage="compute").decode()
    assert hlsl.count("SampleLevel") == 3


def test_a_grid_dds_cannot_hold_is_refused():
    """DDS halves MIP sizes rounding down; a 5x3 pyramid halves rounding up (5x3, 3x2, 2x1, 1x1), so it
    cannot be written as BC (the trainer raises this as an input error naming --latent-format before any
    step); a power-of-two grid can."""
    from mtlx2neural.formats.latent_codec import check_block_shapes
    from mtlx2neural.model.latent import level_shapes

    with pytest.raises(ValueError, match=r"a 5x3 latent grid halves to .* use a power-of-two grid"):
        check_block_shapes(level_shapes(3, 5))
    check_block_shapes(level_shapes(16, 8))


def test_export_of_a_bc_model_lists_dds_textures(tmp_path):
    """export_asset's listing and the layer name the DDS files."""
    asset = tmp_path / "thing.mtlx"
    asset.write_text(RED_MTLX)
    usda, (m,) = export_asset(asset, [(block_model("bc6h"), fake_summary("Red"), tmp_path / "o" / "Red")],
                              tmp_path / "o", "fast")
    assert [p.suffix for p in m.latent_textures] == [".dds"] * 3
    assert m.architecture["latent_format"] == "bc6h" and m.architecture["latent_texture_channels"] == 3
    assert "latents_0.dds" in usda.read_text() or any("latents_0.dds" in p.read_text()
                                                      for p in tmp_path.rglob("*.usda"))


@pytest.mark.slow
def test_a_conversion_trains_through_the_codec_and_ships_dds(tmp_path):
    """``convert_asset`` with ``latent_format=bc1`` on the bundled two-material sample: the trainer reads the
    latents through the emulation in the run's last steps (the checkpoint carries the codec), the layer names DDS
    files, and load_neural reads back exactly the latents the trained model read."""
    from test_export import SAMPLE

    from mtlx2neural.model.checkpoint import load_checkpoint
    from mtlx2neural.pipeline.convert import convert_asset
    from mtlx2neural.pipeline.layout import material_folder
    from mtlx2neural.pipeline.options import ConvertOptions
    from mtlx2neural.train.config import preset

    asset = tmp_path / SAMPLE.name
    shutil.copyfile(SAMPLE, asset)
    cfg = preset("fast", iterations=30, batch=256, latent_format="bc1", preview_iterations=0)
    (summary, *_) = convert_asset(asset, ConvertOptions(train=cfg, progress=False, device="cpu", preset="fast"))
    folder = Path(summary.usd).with_suffix("") / material_folder(summary.material)
    trained = load_checkpoint(folder)
    assert trained.latents.latent_format == "bc1"
    # the codec's range was fitted when its steps began (24 of 30: block_fraction 0.2), and saved with the model
    assert float(trained.latents.codec.codec_scale.max()) != 1.0
    assert sorted(p.name for p in (folder / "neural").glob("latents_*")) == [f"latents_{k}.dds" for k in range(3)]
    loaded = m2n.load_neural(summary.usd, summary.material)
    with torch.no_grad():
        torch.testing.assert_close(loaded.latents.levels[0], trained.latents.level(0), rtol=0, atol=0)


def test_bc1_range_fit_covers_the_latents_with_room_to_move():
    """BC1's per-channel offset and scale cover each channel's range over every level plus 5 % each side, and
    at least 0.25 about the middle for a (nearly) constant channel, so the fine-tune can still move it."""
    from mtlx2neural.formats.latent_codec import LatentCodec

    codec = LatentCodec("bc1", 2)
    levels = [torch.stack([torch.linspace(-1.0, 3.0, 16).view(4, 4), torch.full((4, 4), 0.7)]),
              torch.tensor([[[-2.0]], [[0.7]]])]
    codec.fit(levels)
    torch.testing.assert_close(codec.codec_scale, torch.tensor([5.0 * 1.1, 0.25]))
    torch.testing.assert_close(codec.codec_offset, torch.tensor([0.5 - 2.75, 0.7 - 0.125]))
    t = codec.emulate(levels[0])  # every value inside the range: BC1 error only (6-bit endpoints, 4 levels)
    assert float((t - levels[0]).abs().max()) < 5.5 / 3
    torch.testing.assert_close(t[1], levels[0][1], atol=0.25 / 63, rtol=0)
