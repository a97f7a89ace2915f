"""The MaterialX node of a UDIM material: the atlas holds every tile's pyramid side by side, the
shader picks the tile from floor(uv) (its tile table) and clamps frac(uv) within it, and a tile it
was not trained on shades black, as the Slang module does. Checked in MaterialX's GlslRenderer
(Mesa llvmpipe under Xvfb) against the torch render of the same FP16-rounded model, on a sphere
whose uv is shifted into each tile. A seeded random two-tile model (tiles 1002 and 1011: no 1001,
so a plain [0,1]^2 read would show nothing)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from mtlx2neural.codegen.glsl_render import (
    directional_light_rig,
    gl_unavailable,
    read_exr,
    render_plan,
    write_sphere_obj,
)
from mtlx2neural.codegen.materialx_node import (
    generate_node_shader,
    latent_atlas,
    node_names,
    write_materialx_node,
)
from mtlx2neural.codegen.materialx_shader import atlas_layout
from mtlx2neural.export.latents import write_latent_textures
from mtlx2neural.formats.weights import write_weights
from mtlx2neural.imaging.mip_chain import read_mip_chain
from mtlx2neural.model.neural_material import NeuralMaterial
from mtlx2neural.render.geometry import Camera, Sphere
from mtlx2neural.render.lighting import DirectionalLight
from mtlx2neural.render.renderer import image_errors, render_scene
from mtlx2neural.render.udim_view import TileView

TILES = [1002, 1011]
LIGHT = (0.4, 0.7, 0.6)  # towards the light, world space (y up)
INTENSITY = 3.0


@pytest.fixture(scope="module")
def udim_node(tmp_path_factory):
    """(folder, FP16-rounded model, .mtlx) of a seeded random 8x8, 8-channel, two-tile model."""
    torch.manual_seed(0)
    model = NeuralMaterial((8, 8), in_dim=2, latent_dim=8, frames=2, decoder="2x16", tiles=TILES)
    with torch.no_grad():
        for lv in model.latents.levels:
            lv.copy_(torch.randn(lv.shape) * 0.5)
        for p in model.parameters():
            p.copy_(p.half().float())  # what the export stores
    model.train(False)
    folder = tmp_path_factory.mktemp("udim_node") / "neural"
    write_latent_textures(list(model.latents.levels), folder, tiles=TILES)
    write_weights(model, folder)
    return folder, model, write_materialx_node(folder, "Udim", folder)


def test_udim_atlas_holds_each_tile_side_by_side_and_the_shader_has_the_tile_table(udim_node):
    folder, model, mtlx = udim_node
    atlas = read_mip_chain(folder / "latent_atlas_0.exr")[0]
    chains = [read_mip_chain(folder / f"latents_0.{t}.exr") for t in TILES]
    (_, (h, w)) = atlas_layout([lv.shape[:2] for lv in chains[0]])
    assert atlas.shape[:2] == (h, 2 * w)
    # bit-identical: the atlas copies each tile's FP16 levels
    assert np.array_equal(atlas, latent_atlas(chains)) and np.array_equal(atlas[:, :w], latent_atlas(chains[0]))
    assert np.array_equal(atlas[:8, w:w + 8], chains[1][0])  # tile 1011's level 0 at its block's corner
    text = (folder / node_names("Udim").glsl).read_text()
    assert "int nm_Udim_udimSlot(vec2 texcoord)" in text
    assert "if (udim == 1002) return 0;" in text and "if (udim == 1011) return 1;" in text
    assert f"r.x += slot * {w};" in text and "clamp(x, 0, r.z - 1)" in text
    for target in ("genglsl", "genslang"):  # MaterialX generates a complete shader from it
        pixel = generate_node_shader(mtlx, target).getSourceCode("pixel")
        assert "nm_Udim_udimSlot(texcoord)" in pixel and "$" not in pixel


def _shifted_sphere(path: Path, du: float, dv: float) -> Path:
    """write_sphere_obj's sphere with every uv moved by (du, dv): the sphere shown as another tile."""
    lines = write_sphere_obj(path).read_text().splitlines()
    out = []
    for line in lines:
        if line.startswith("vt "):
            u, v = map(float, line.split()[1:])
            line = f"vt {u + du:.7f} {v + dv:.7f}"
        out.append(line)
    path.write_text("\n".join(out) + "\n")
    return path


@pytest.mark.slow
@pytest.mark.skipif(gl_unavailable() is not None, reason=f"MaterialX's GLSL renderer: {gl_unavailable()}")
def test_glsl_renderer_shows_each_udim_tile_and_black_outside_them(udim_node, tmp_path):
    folder, model, mtlx = udim_node
    (tmp_path / "rig.mtlx").write_text(directional_light_rig([-c for c in LIGHT], INTENSITY))
    shifts = {1002: (1.0, 0.0), 1011: (0.0, 1.0), 1003: (2.0, 0.0)}  # 1003: not trained
    gl = {}
    for tile, (du, dv) in shifts.items():
        obj = _shifted_sphere(tmp_path / f"sphere_{tile}.obj", du, dv)
        out = tmp_path / f"gl_{tile}.exr"
        render_plan({"geometry": str(obj), "lights": str(tmp_path / "rig.mtlx"),
                     "renders": [{"mtlx": str(mtlx), "out": str(out), "size": 256, "frames": 0}]})
        img = read_exr(out)
        gl[tile] = img[..., :3].reshape(128, 2, 128, 2, 3).mean((1, 3))  # 2x2 samples per pixel
        if tile == 1003:
            covered = img[..., 3] > 0.5
            assert covered.mean() > 0.3 and float(np.abs(img[..., :3][covered]).max()) == 0.0
    torch.set_num_threads(1)
    errors = {}
    for tile in TILES:
        ours = render_scene(TileView(model, tile), Sphere(), Camera(0.0, 0.0, 3.0, 45.0),
                            [DirectionalLight(LIGHT, INTENSITY)], res=128, spp=8, texels=(8, 8), seed=1,
                            footprint=0.5)
        errors[tile] = image_errors(ours, gl[tile])["flip"]
    other = image_errors(gl[1002], gl[1011])["flip"]
    print(f"HDR FLIP GlslRenderer vs torch per UDIM tile: {errors}; tile 1002 vs 1011: {other:.4f}", file=sys.stderr)
    # 0.025: measured 0.013 for both tiles (the same FP16 networks and latents, read the same way;
    # what is left is rasterised vs traced sampling at the silhouette and of a strongly varying
    # random code); a wrong tile or a misplaced block shows the other tile's random code, 0.042 away.
    assert all(e <= 0.025 for e in errors.values()), errors
    assert other > 2 * max(errors.values()), (other, errors)
