"""The parameter atlas and the universal network's training script (mtlx2neural.universal.atlas, .train)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mtlx2neural.formats.weights import upgrade_environment_head
from mtlx2neural.universal.atlas import CELL_SIZES, MAX_TILT_DEGREES, input_texture
from mtlx2neural.universal.train import train_universal
from mtlx2neural.universal.weights import NETWORK_FIELDS, load_weights


def test_each_input_spans_its_range_in_cells_of_every_size():
    a = input_texture("metallic", 128, np.random.default_rng(0))
    b = input_texture("metallic", 128, np.random.default_rng(0))
    assert np.array_equal(a, b)  # seeded
    m = a[..., 0]
    # metallic: mostly at its ends (0 and 1), the rest in between
    assert (m == 0).mean() > 0.2 and (m == 1).mean() > 0.2 and ((m > 0) & (m < 1)).mean() > 0.05
    # every quadrant has square cells of one size: the number of distinct values per quadrant tells which
    counts = sorted(len(np.unique(m[r:r + 64, c:c + 64])) for r in (0, 64) for c in (0, 64))
    assert counts[0] <= 4 and counts[-1] > 500  # the 32-texel cells; per texel, a fifth of 4096 not at an end
    assert len(CELL_SIZES) == 4
    n = input_texture("normal", 64, np.random.default_rng(1)).reshape(-1, 3)
    assert np.allclose(np.linalg.norm(n, axis=1), 1, atol=1e-5)
    tilt = np.degrees(np.arccos(np.clip(n[:, 2], -1, 1)))
    assert tilt.max() <= MAX_TILT_DEGREES + 1e-3 and (tilt < 1e-3).mean() > 0.2 and tilt.max() > 30


@pytest.mark.slow
@pytest.mark.parametrize("model", ["UsdPreviewSurface", "standard_surface", "open_pbr_surface", "gltf_pbr"])
def test_the_script_reproduces_the_shipped_layout_and_shape(tmp_path, model):
    shipped = load_weights(model)
    if shipped is None:
        pytest.skip(f"no universal {model} network in this checkout")
    data = train_universal(model, steps=10, size=16, workdir=tmp_path, progress=False)
    # the script's atlas compiles to the layout the shipped encoder reads, with the shipped network's shape
    assert data["channels"] == shipped["channels"] and data["shape"] == shipped["shape"]
    assert set(data["shape"]) == set(NETWORK_FIELDS)
    # the shipped decoder as every consumer reads it: a head shipped before the sharp lobe grows a silent one
    read = upgrade_environment_head(dict(shipped["decoder"]), prefix="environment.")
    assert {k: tuple(v.shape) for k, v in data["decoder"].items()} == {k: tuple(v.shape) for k, v in read.items()}
    assert math.isfinite(data["provenance"]["final_loss_brdf"])
    assert "--steps 10 --size 16" in data["provenance"]["command"]


def test_the_standard_surface_atlas_reads_like_a_material_of_its_model(tmp_path):
    """The Standard Surface atlas (its normal through a normalmap of the encoded texture) compiles to the
    stack layout of MaterialX's textured brass in its canonical form, so the network trained on it reads
    real materials; its tints are white half the time."""
    import MaterialX as mx
    from conftest import shared_path

    from mtlx2neural.graph.compile import compile_material
    from mtlx2neural.textures.parameter_stack import build_parameter_stack
    from mtlx2neural.universal.canonical import canonical_document, canonical_name
    from mtlx2neural.universal.train import atlas_material

    _, _, atlas = atlas_material(tmp_path, "standard_surface", 32, 0)
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(shared_path("materialx", "resources", "Materials", "Examples", "StandardSurface",
                                            "standard_surface_brass_tiled.mtlx")))
    brass = compile_material(canonical_document(doc, "Tiled_Brass"), "Tiled_Brass", allow_missing_textures=True)
    layout = [(canonical_name(c.name), c.width) for c in build_parameter_stack(brass).channels]
    assert [(canonical_name(c.name), c.width) for c in atlas.channels] == layout
    tint = input_texture("specular_color", 128, np.random.default_rng(0), "standard_surface").reshape(-1, 3)
    white = np.all(tint == 1, axis=1).mean()
    assert 0.3 < white < 0.7 and len(np.unique(tint[:, 0])) > 100
