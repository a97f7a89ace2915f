"""The generated Slang module of a UDIM material (tile table, udimSlot, NMBufferTiledLatents) on
slangpy's CPU device, against the torch model at both trained tiles and at an untrained one.

Tolerances (relative, floor 1e-3 as in test_codegen.py): FP32 variant vs the float64 torch model on
the same float32 latents and weights: 1e-5 for eval after the per-tile fetch (float32 bilinear
weights and network sums; measured max reported by the test). FP16 variant: 3e-2 (weights rounded
to 11 significant bits, half accumulation; test_codegen.py's bound for eval).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from neural_models import randomise_latents
from test_codegen import make_inputs, make_model, rel, report

from mtlx2neural.codegen import as_spec, generate_slang
from mtlx2neural.codegen.cpu import CpuMaterial, slangpy_available
from mtlx2neural.contract import ShadingPoint

OK, REASON = slangpy_available()
pytestmark = pytest.mark.skipif(not OK, reason=f"slangpy CPU device unavailable: {REASON}")
TILES = [1001, 1002]


def udim_model():
    """test_codegen's model A (spread-out weights) with a two-tile (5, 7) latent pyramid."""
    base = make_model()
    torch.manual_seed(21)
    m = type(base)((5, 7), in_dim=0, latent_dim=8, frames=2, decoder="2x16", tiles=TILES)
    state = {k: v for k, v in base.state_dict().items() if not k.startswith("latents.")}
    m.load_state_dict({**m.state_dict(), **state})
    randomise_latents(m)
    return m.train(False)


@pytest.fixture(scope="module")
def udim():
    m = udim_model()
    return m, as_spec(m), generate_slang(m, "Udim")


def test_module_has_the_tile_table(udim):
    _, spec, src = udim
    assert spec.udim_tiles == TILES
    assert "public static const int NM_Udim_TILES[2] = { 1001, 1002 };" in src
    assert "public int NM_Udim_udimSlot(float2 uv)" in src
    plain = generate_slang(make_model(), "Plain")
    assert "udimSlot" not in plain and "_TILES" not in plain


@pytest.mark.parametrize("variant,tol", [("FP32", 1e-5), ("FP16", 3e-2)])
def test_udim_fetch_eval_matches_torch_per_tile(udim, variant, tol, tmp_path):
    model, spec, src = udim
    n = 4096
    g = torch.Generator().manual_seed(4)
    # A third in each trained tile, a third in tile 1011 (on no trained tile: black, slot -1).
    uv = torch.rand(n, 2, generator=g) + torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])[torch.arange(n) % 3]
    lod = torch.rand(n, generator=g) * (model.latents.num_levels + 1) - 0.5
    u = torch.rand(n, generator=g)
    _, wi, wo, _ = make_inputs(n, 8, seed=6)
    trained = (torch.arange(n) % 3) < 2
    m64 = udim_model().double()
    with torch.no_grad():
        want = m64.eval(wi[trained].double(), wo[trained].double(),
                        ShadingPoint(uv=uv[trained].double(), lod=lod[trained].double(),
                                     u_level=u[trained].double())).numpy()
    cm = CpuMaterial(src, "Udim", spec, variant, workdir=tmp_path)
    tiles = [[lv[t].detach().numpy() for lv in model.latents.levels] for t in range(len(TILES))]
    got, slot = cm.udim_fetch_eval(tiles, uv.numpy(), lod.numpy(), u.numpy(), wi.numpy(), wo.numpy())
    assert slot.tolist() == [(k % 3) if k % 3 < 2 else -1 for k in range(n)]
    assert np.all(got[~trained.numpy()] == 0)
    err = rel(got[trained.numpy()], want, 1e-3)
    report(f"UDIM {variant} fetch+eval vs torch", err)
    assert np.abs(want).max() > 0 and err.max() <= tol


def test_materialx_node_of_a_udim_material_from_its_export(tmp_path):
    """The node reads every tile (its atlas and tile table: tests/codegen/test_materialx_node_udim.py),
    written from the export folder (manifest udim_tiles, latents_<k>.<UDIM>.exr); a missing tile file
    is named."""
    from mtlx2neural.codegen.materialx_node import write_materialx_node
    from mtlx2neural.errors import InputError
    from mtlx2neural.export.latents import write_latent_textures
    from mtlx2neural.formats.weights import write_weights

    model = udim_model()
    export = tmp_path / "export"
    write_latent_textures(list(model.latents.levels), export, tiles=[1001, 1002])
    write_weights(model, export)
    mtlx = write_materialx_node(export, "Udim", tmp_path / "node")
    assert "if (udim == 1002) return 1;" in (mtlx.parent / "NeuralMaterial_Udim.glsl").read_text()
    (export / "latents_1.1002.exr").unlink()
    with pytest.raises(InputError, match=r"latents_1\.1002\.exr"):
        write_materialx_node(export, "Udim", tmp_path / "node2")
