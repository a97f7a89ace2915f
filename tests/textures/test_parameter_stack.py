"""Parameter maps of real textured materials, checked against direct OpenImageIO reads."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest
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


@pytest.mark.slow
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


# 4x4 specular_rotation map (fraction of a turn, row 0 at the top): each 2x2 block is one level-1 texel.
# Top-left: 0 and 90 degrees in a checker; top-right: 0 and 45 degrees; bottom-left: all 30 degrees;
# bottom-right: all 0.
ROTATIONS = np.array([[0.0, 0.25, 0.0, 0.125],
                      [0.25, 0.0, 0.125, 0.0],
                      [30 / 360, 30 / 360, 0.0, 0.0],
                      [30 / 360, 30 / 360, 0.0, 0.0]], dtype=np.float32)


def _rotated_metal(tmp_path, rotation: np.ndarray | None = None, roughness: np.ndarray | None = None,
                   constant_rotation: float = 0.0):
    """A standard_surface metal, specular_anisotropy 0.8, specular_roughness 0.4, with a textured
    specular_rotation (``rotation`` [H, W]) or a constant one and a textured roughness."""
    import MaterialX as mx
    from conftest import write_float_image

    from mtlx2neural.graph import compile_material

    doc = mx.createDocument()
    s = doc.addNode("standard_surface", "s", "surfaceshader")
    s.setInputValue("metalness", 1.0)
    s.setInputValue("specular_anisotropy", 0.8)
    s.setInputValue("specular_roughness", 0.4)
    s.setInputValue("specular_rotation", constant_rotation)
    for name, img in (("specular_rotation", rotation), ("specular_roughness", roughness)):
        if img is not None:
            write_float_image(tmp_path / f"{name}.exr", np.repeat(img[..., None], 3, -1))
            node = doc.addNode("image", name, "float")
            node.setInputValue("file", str(tmp_path / f"{name}.exr"), "filename")
            s.setConnectedNode(name, node)
    doc.addMaterialNode("M", s)
    return compile_material(doc, "M")


def _lobe(values):
    return (next(v for k, v in values.items() if k.endswith("metal_bsdf.tangent")),
            next(v for k, v in values.items() if k.endswith("metal_bsdf.roughness")))


def _axis_degrees(tangent):
    """Angle of each tangent's axis in the xy plane, degrees in [0, 180)."""
    return np.degrees(np.arctan2(tangent[:, 1], tangent[:, 0])) % 180.0


def _axis_difference(a, b):
    d = np.abs(a - b) % 180.0
    return np.minimum(d, 180.0 - d)


def test_level_zero_keeps_each_texels_rotation(tmp_path):
    stack = build_parameter_stack(_rotated_metal(tmp_path, ROTATIONS))
    assert stack.resolution == (4, 4)
    tangent, alpha = (v.numpy().astype(np.float64) for v in _lobe(stack.texel_values(0)))
    # standard_surface turns the tangent clockwise about the normal (MaterialX's rotate3d), by 360 x rotation.
    want = (-360.0 * ROTATIONS.reshape(-1)) % 180.0
    # Level 0 holds each texel's own lobe: the moments round-trip up to float32 rounding (~1e-5 rad).
    assert _axis_difference(_axis_degrees(tangent), want).max() < 0.01
    # Every texel has the same anisotropic alpha (specular_roughness 0.4, anisotropy 0.8).
    assert np.ptp(alpha, 0).max() < 1e-6 and alpha[0, 1] < 0.5 * alpha[0, 0]


def test_coarse_level_averages_rotations_as_lean_predicts(tmp_path):
    stack = build_parameter_stack(_rotated_metal(tmp_path, ROTATIONS))
    ax, ay = (float(a) for a in _lobe(stack.texel_values(0))[1][0])
    tangent, alpha = (v.numpy().astype(np.float64) for v in _lobe(stack.texel_values(1)))

    def expected(degrees):  # LEAN: the block's mean slope covariance R diag(ax^2, ay^2) R^T / 2
        cov = 0
        for d in degrees:
            c, s = np.cos(np.radians(d)), np.sin(np.radians(d))
            r = np.array([[c, -s], [s, c]])
            cov = cov + r @ np.diag([ax * ax, ay * ay]) @ r.T / 2 / len(degrees)
        lam, vec = np.linalg.eigh(cov)
        return np.sqrt(2 * lam[::-1]), np.degrees(np.arctan2(vec[1, 1], vec[0, 1])) % 180.0

    # Level-1 texels (row-major): 0/90 checker, 0/45 checker, all 30 degrees, all 0 (clockwise: -30, -45).
    blocks = ([0, 90, 0, 90], [0, -45, 0, -45], [-30] * 4, [0] * 4)
    # Moments are averaged in float32 and read back exactly: 1e-5 on alpha, 0.01 degrees on the axis.
    for i, degrees in enumerate(blocks):
        a, axis = expected(degrees)
        np.testing.assert_allclose(alpha[i], a, atol=1e-5)
        if a[0] > a[1] * 1.001:  # an isotropic lobe has no axis
            assert _axis_difference(_axis_degrees(tangent[i:i + 1]), axis).max() < 0.01, (i, tangent[i], axis)
    # The 0/90 block is round, alpha sqrt((ax^2 + ay^2) / 2) both ways; the 0/45 block keeps some anisotropy
    # along -22.5 degrees; uniform blocks keep their lobe.
    np.testing.assert_allclose(alpha[0], [np.sqrt((ax * ax + ay * ay) / 2)] * 2, atol=1e-5)
    assert alpha[1, 1] / alpha[1, 0] > ay / ax and alpha[1, 1] / alpha[1, 0] < 0.9
    np.testing.assert_allclose(alpha[2], [ax, ay], atol=1e-5)


def test_a_constant_rotation_is_kept_when_roughness_varies(tmp_path):
    """A lobe LEAN-filtered because its roughness is textured takes its tangent from the constant rotation."""
    rough = np.array([[0.3, 0.5], [0.5, 0.3]], dtype=np.float32)
    stack = build_parameter_stack(_rotated_metal(tmp_path, roughness=rough, constant_rotation=0.1))
    tangent = _lobe(stack.texel_values(0))[0].numpy().astype(np.float64)
    assert _axis_difference(_axis_degrees(tangent), (-36.0) % 180.0).max() < 0.01
