"""Parameter maps of real textured materials, checked against direct OpenImageIO reads."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
from conftest import shared_path

import mtlx2neural as m2n
from mtlx2neural.imaging.colour import convert
from mtlx2neural.textures.parameter_stack import build_parameter_stack

EXAMPLES = ("materialx", "resources", "Materials", "Examples", "StandardSurface")


def _read_linear(path, colorspace="srgb_texture"):
    buf = oiio.ImageBuf(str(path))
    px = buf.get_pixels(oiio.FLOAT)
    return convert(px[..., :3].reshape(-1, 3), colorspace, "lin_rec709") if colorspace != "raw" else px


def _channel(stack, suffix):
    names = [c.name for c in stack.channels if c.name.endswith(suffix)]
    assert names, f"no channel ending in {suffix}: {[c.name for c in stack.channels]}"
    return names[0]


def test_chessboard_maps_match_the_source_textures():
    path = shared_path(*EXAMPLES, "standard_surface_chess_set.mtlx")
    m = m2n.load_reference(path, "M_Chessboard")
    tex = path.parent / "chess_set" / "chessboard_base_color.jpg"
    spec = oiio.ImageInput.open(str(tex)).spec()
    stack = build_parameter_stack(m.compiled, resolution=(spec.height, spec.width))
    color = _channel(stack, "diffuse_bsdf.color")
    maps = stack.texel_values(0)
    ours = maps[color].numpy().astype(np.float64)  # float64: 4M-texel means
    direct = _read_linear(tex).astype(np.float64)
    # Same texel grid, same OCIO conversion: the maps are the texels (float32 rounding).
    np.testing.assert_allclose(ours.mean(0), direct.mean(0), rtol=1e-4)
    np.testing.assert_allclose(np.percentile(ours, [5, 50, 95], axis=0),
                               np.percentile(direct, [5, 50, 95], axis=0), rtol=1e-3, atol=1e-5)
    # The normal map makes the specular lobes LEAN-filtered; constants stay constants.
    assert any(g.endswith("specular_bsdf") for g in stack.lean_groups)
    assert any(k.endswith("specular_bsdf.ior") for k in stack.constants)
    # The box pyramid preserves the mean colour (power-of-two texture).
    coarse = stack.texel_values(len(stack.levels) - 1)[color].numpy().astype(np.float64)
    np.testing.assert_allclose(coarse[0], ours.mean(0), rtol=1e-4)
    assert stack.levels[-1].shape[1:] == (1, 1)


def test_wood_tiled_statistics_follow_its_textures():
    path = shared_path(*EXAMPLES, "standard_surface_wood_tiled.mtlx")
    m = m2n.load_reference(path)
    stack = build_parameter_stack(m.compiled, resolution=(512, 512))
    ours = stack.texel_values(0)[_channel(stack, "diffuse_bsdf.color")].numpy().astype(np.float64)
    direct = _read_linear(shared_path("materialx", "resources", "Images", "wood_color.jpg")).astype(np.float64)
    # 4x4 tiling on a 512 grid samples every second texel of the 1024 texture, bilinearly:
    # the mean agrees to ~1%.
    np.testing.assert_allclose(ours.mean(0), direct.mean(0), rtol=0.02)
    values = stack.texel_values(0)
    rough = values[next(k for k in values if k.endswith("specular_bsdf.roughness"))].numpy().astype(np.float64)
    r = oiio.ImageBuf(str(shared_path("materialx", "resources", "Images", "wood_roughness.jpg"))).get_pixels(
        oiio.FLOAT)[..., 0].ravel()
    # roughness_anisotropy with anisotropy 0.5: alpha_x = r^2 / sqrt(0.5), alpha_y = r^2 sqrt(0.5).
    expected = np.stack([np.minimum(r ** 2 / np.sqrt(0.5), 1.0), r ** 2 * np.sqrt(0.5)], -1)
    np.testing.assert_allclose(rough.mean(0), expected.astype(np.float64).mean(0), rtol=0.03)


def test_automatic_resolution_counts_tiling():
    path = shared_path(*EXAMPLES, "standard_surface_wood_tiled.mtlx")
    m = m2n.load_reference(path)
    from mtlx2neural.textures import parameter_stack as ps

    h, w, notes = ps.texture_resolution(m.compiled)
    spec = oiio.ImageInput.open(str(shared_path("materialx", "resources", "Images", "wood_color.jpg"))).spec()
    # The texture repeats 4 times across UV space (uvtiling 4): 4x its texels, up to MAX_RES.
    expected = min(4 * spec.width, ps.MAX_RES)
    assert (h, w) == (expected, expected)
    assert bool(notes) == (4 * spec.width > ps.MAX_RES)


def test_uniform_material_has_no_varying_channels():
    m = m2n.load_reference(shared_path(*EXAMPLES, "standard_surface_copper.mtlx"))
    stack = build_parameter_stack(m.compiled, resolution=(4, 4))
    assert stack.channels == [] and stack.levels[0].shape == (0, 4, 4)
    assert stack.constants


def test_brick_normal_map_matches_the_source_texture():
    from mtlx2neural.graph import compile_material
    from mtlx2neural.scene import find_material

    src = find_material(shared_path(*EXAMPLES, "standard_surface_brick_procedural.mtlx"))
    # Untile the pattern (uvtiling 3 -> 1) so that the grid's texel centres are the texture's.
    src.document.getNodeGraph("NG_BrickPattern").getInput("uvtiling").setValue(1.0)
    compiled = compile_material(src.document, src.material)
    tex = shared_path("materialx", "resources", "Images", "brick_normal.jpg")
    spec = oiio.ImageInput.open(str(tex)).spec()
    stack = build_parameter_stack(compiled, resolution=(spec.height, spec.width))
    values = stack.texel_values(0)
    ours = values[next(k for k in values if k.endswith("diffuse_bsdf.normal"))].numpy().astype(np.float64)
    px = oiio.ImageBuf(str(tex)).get_pixels(oiio.FLOAT).reshape(-1, 3).astype(np.float64)
    n = px * 2.0 - 1.0  # MaterialX normalmap: tangent-space decode, geometric frame = identity
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    # Same texels, float32 maths on our side: 1e-5.
    np.testing.assert_allclose(ours.mean(0), n.mean(0), atol=1e-5)
    np.testing.assert_allclose(ours.std(0), n.std(0), atol=1e-5)
    # The specular lobe is LEAN-filtered and reproduces the same normals at level 0.
    spec_n = values[next(k for k in values if k.endswith("specular_bsdf.normal"))].numpy().astype(np.float64)
    np.testing.assert_allclose(spec_n.mean(0), n.mean(0), atol=1e-4)
