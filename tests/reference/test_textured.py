"""The reference with UVs: eval(wi, wo, uv) follows the textures, colour-managed with OCIO."""

from __future__ import annotations

import math

import MaterialX as mx
import numpy as np
import pytest
import torch
from conftest import shared_path, write_float_image

import mtlx2neural as m2n
from mtlx2neural.graph import compile_material
from mtlx2neural.imaging.colour import convert
from mtlx2neural.reference import ReferenceMaterial


@pytest.mark.parametrize("colorspace", ["srgb_texture", "acescg", "raw"])
def test_diffuse_colour_follows_texture_texels(tmp_path, colorspace):
    rng = np.random.default_rng(0)
    img = rng.uniform(0.05, 0.95, size=(8, 8, 3)).astype(np.float32)
    path = tmp_path / "albedo.exr"
    write_float_image(path, img)
    doc = mx.createDocument()
    doc.setColorSpace("lin_rec709")
    tex = doc.addNode("image", "albedo", "color3")
    f = tex.setInputValue("file", str(path), "filename")
    f.setColorSpace(colorspace)
    d = doc.addNode("oren_nayar_diffuse_bsdf", "d", "BSDF")
    d.setConnectedNode("color", tex)
    s = doc.addNode("surface", "s", "surfaceshader")
    s.setConnectedNode("bsdf", d)
    doc.addMaterialNode("M", s)
    m = ReferenceMaterial(compile_material(doc, "M"))
    # Texel centres: column c, file row r (row 0 = top = v near 1).
    r, c = np.meshgrid(np.arange(8), np.arange(8), indexing="ij")
    uv = torch.tensor(np.stack([(c.ravel() + 0.5) / 8, 1 - (r.ravel() + 0.5) / 8], -1), dtype=torch.float32)
    n = uv.shape[0]
    up = torch.tensor([[0.0, 0.0, 1.0]]).expand(n, 3)
    got = m.eval(up, up, uv).numpy() * math.pi  # Lambertian at normal incidence: colour / pi
    expected = convert(img.reshape(-1, 3), colorspace, "lin_rec709")
    # OCIO and the reference both run in float32: 1e-5 relative.
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)


def test_wood_varies_with_uv_like_its_texture():
    path = shared_path("materialx", "resources", "Materials", "Examples", "StandardSurface",
                       "standard_surface_wood_tiled.mtlx")
    m = m2n.load_reference(path)
    g = torch.Generator().manual_seed(0)
    uv = torch.rand(512, 2, generator=g)
    up = torch.tensor([[0.0, 0.3, 0.954]]).expand(512, 3)
    f = m.eval(up, up, uv)
    assert float(f.std(0).max()) > 5e-3  # spatially varying (red std is 0.009 here)
    # Tiling 4x4: uv and uv + 0.25 land on the same texel. (uv + 0.25) * 4 rounds differently
    # from uv * 4 + 1 in float32 (~1e-6 texels), which moves bilinear weights slightly: 1e-3.
    torch.testing.assert_close(m.eval(up, up, uv + 0.25), f, rtol=1e-3, atol=1e-5)
