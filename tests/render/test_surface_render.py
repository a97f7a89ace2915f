"""The renderer shows emission and cut-outs (mtlx2neural.render.renderer.render_scene).

A material here is a stand-in with a black BRDF and its own surface maps: what the pixels show is
then exactly the emission and the coverage, so the expected values are exact (tolerance 1e-5:
float32 sums over the samples)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mtlx2neural.render import renderer
from mtlx2neural.render.geometry import Camera, Plane
from mtlx2neural.render.in_scene import mesh_from_triangles
from mtlx2neural.render.lighting import DirectionalLight
from mtlx2neural.render.renderer import render_scene
from mtlx2neural.textures.surface_maps import SurfaceMaps, SurfacesBeside


class BlackEmitter(SurfacesBeside):
    """eval 0 everywhere; emission and opacity from ``surface``."""

    def __init__(self, surface: SurfaceMaps):
        self.surface = surface

    def eval(self, wi, wo, at=None):
        return torch.zeros(wi.shape[0], 3)


def _left_half_mask(res: int = 8) -> SurfaceMaps:
    """Emission (1, 2, 3) where u < 0.5 (covered), 0.0 opacity elsewhere: a mask."""
    o = torch.zeros(1, res, res)
    o[:, :, : res // 2] = 1.0
    e = torch.tensor([1.0, 2.0, 3.0])[:, None, None].expand(3, res, res).contiguous()
    return SurfaceMaps(emission_levels=[e], opacity_levels=[o], alpha_mode="mask")


def test_emission_shows_without_any_light():
    maps = SurfaceMaps(emission_constant=(0.5, 0.25, 2.0))
    img = render_scene(BlackEmitter(maps), Plane(tiles=1.0), Camera(0.0, 60.0, 3.0), [], res=24, spp=1)
    hit = img.sum(-1) > 0
    assert hit.mean() > 0.2
    np.testing.assert_allclose(img[hit], np.broadcast_to([0.5, 0.25, 2.0], img[hit].shape), rtol=1e-5)


def test_a_cut_out_lets_the_background_through():
    """Half the plane's uv is empty: about half the plane's pixels are background (0), the rest emission."""
    mat = BlackEmitter(_left_half_mask(16))
    full = render_scene(BlackEmitter(SurfaceMaps(emission_constant=(1.0, 2.0, 3.0))), Plane(tiles=1.0),
                        Camera(0.0, 80.0, 3.0), [DirectionalLight((0, 1, 0), 1.0)], res=32, spp=1)
    cut = render_scene(mat, Plane(tiles=1.0), Camera(0.0, 80.0, 3.0), [DirectionalLight((0, 1, 0), 1.0)],
                       res=32, spp=1)
    plane = full.sum(-1) > 0
    shown = cut.sum(-1) > 0
    assert not (shown & ~plane).any()
    assert 0.4 < shown.sum() / plane.sum() < 0.6
    np.testing.assert_allclose(cut[shown], np.broadcast_to([1.0, 2.0, 3.0], cut[shown].shape), rtol=1e-5)


def test_a_ray_continues_through_a_cut_out_to_what_lies_behind():
    """Two quads, the front one in the empty half of uv, the back one in the covered half: the camera sees
    the back quad's emission through the front one (without the continuation the image would be black)."""
    def quad(z, u0, u1):
        p = np.array([[-1, -1, z], [1, -1, z], [1, 1, z], [-1, 1, z]], np.float32)
        uv = np.array([[u0, 0], [u1, 0], [u1, 1], [u0, 1]], np.float32)
        n = np.tile(np.array([[0, 0, 1]], np.float32), (4, 1))
        idx = [[0, 1, 2], [0, 2, 3]]
        return p[idx], uv[idx], n[idx]

    front, back = quad(0.5, 0.6, 0.9), quad(-0.5, 0.1, 0.4)
    mesh = mesh_from_triangles(*(np.concatenate([a, b]) for a, b in zip(front, back)))
    img = render_scene(BlackEmitter(_left_half_mask(16)), mesh, Camera(0.0, 0.0, 6.0), [], res=24, spp=1)
    centre = img[8:16, 8:16]
    np.testing.assert_allclose(centre, np.broadcast_to([1.0, 2.0, 3.0], centre.shape), rtol=1e-5)
    # Several jittered passes shaded together (renderer.PASS_BATCH_POINTS) keep each layer's hits on their pixels:
    # the same image as one pass at a time.
    many = render_scene(BlackEmitter(_left_half_mask(16)), mesh, Camera(0.0, 0.0, 6.0), [], res=24, spp=6)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(renderer, "PASS_BATCH_POINTS", 1)
        alone = render_scene(BlackEmitter(_left_half_mask(16)), mesh, Camera(0.0, 0.0, 6.0), [], res=24, spp=6)
    np.testing.assert_allclose(many, alone, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(many[8:16, 8:16], centre, rtol=1e-5)


def test_a_scene_draws_each_triangle_with_its_own_material():
    """Two side-by-side quads, material index 0 and 1: the left half shows the first emitter, the right the
    second, each at its own colour (a list of materials and a per-triangle index)."""
    def quad(x0, x1):
        p = np.array([[x0, -1, 0], [x1, -1, 0], [x1, 1, 0], [x0, 1, 0]], np.float32)
        uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
        n = np.tile(np.array([[0, 0, 1]], np.float32), (4, 1))
        idx = [[0, 1, 2], [0, 2, 3]]
        return p[idx], uv[idx], n[idx]

    mesh = mesh_from_triangles(*(np.concatenate([a, b]) for a, b in zip(quad(-1.05, -0.05), quad(0.05, 1.05))))
    # mesh_from_triangles keeps triangle order: the first two are the left quad
    mesh.material_index = torch.tensor([0, 0, 1, 1])
    red, blue = (BlackEmitter(SurfaceMaps(emission_constant=c)) for c in ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)))
    img = render_scene([red, blue], mesh, Camera(0.0, 0.0, 5.0), [], res=32, spp=1, texels=[(1, 1), (1, 1)])
    left, right = img[12:20, 8:14], img[12:20, 18:24]
    np.testing.assert_allclose(left, np.broadcast_to([1.0, 0.0, 0.0], left.shape), rtol=1e-5)
    np.testing.assert_allclose(right, np.broadcast_to([0.0, 0.0, 1.0], right.shape), rtol=1e-5)
