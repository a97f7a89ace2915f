"""The translation of the torch renderer's scenes into Mitsuba (:mod:`mtlx2neural.mitsuba.scene`): uv, bitmap
orientation, camera, distant lights, environment maps, emission and cut-outs. Mitsuba's built-in ``diffuse``
stands in for the project's plugins, and small torch materials here for the project's models."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from mitsuba_samples import mi  # noqa: F401

from mtlx2neural.contract import as_point
from mtlx2neural.imaging.grid_lookup import bilinear_periodic
from mtlx2neural.mitsuba import scene as ms
from mtlx2neural.render.geometry import PinholeCamera
from mtlx2neural.render.in_scene import InScene, mesh_from_triangles
from mtlx2neural.render.lighting import (
    DirectionalLight,
    EnvironmentMap,
    direction_to_uv,
)
from mtlx2neural.render.renderer import render_scene


class Lambert:
    """A torch Lambertian with RGB ``albedo`` (the contract's eval includes the cosine), optionally
    emitting ``emission_fn(uv)`` and with a cut-out ``opacity_fn(uv)`` (alpha-tested at 0.5)."""

    def __init__(self, albedo=(0.5, 0.5, 0.5), emission_fn=None, opacity_fn=None):
        self.albedo = torch.tensor(albedo, dtype=torch.float32)
        self.emission_fn, self.opacity_fn = emission_fn, opacity_fn
        self.alpha_cutoff = 0.5 if opacity_fn is not None else None

    def eval(self, wi, wo, at=None):
        ok = ((wi[:, 2] > 0) & (wo[:, 2] > 0)).float()
        return (wo[:, 2] * ok / math.pi)[:, None] * self.albedo

    def emission(self, at=None):
        return None if self.emission_fn is None else self.emission_fn(as_point(at).uv)

    def opacity(self, at=None):
        return None if self.opacity_fn is None else self.opacity_fn(as_point(at).uv)


def diffuse(albedo) -> dict:
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [float(a) for a in albedo]}}


def quad(x0, x1, y0, y1, z=0.0):
    """Two triangles of the rectangle [x0, x1] x [y0, y1] at depth z facing +z, uv (0, 0) at (x0, y0), u along
    +x, v along +y: per-corner positions, uvs and normals."""
    p = np.array([[[x0, y0, z], [x1, y0, z], [x1, y1, z]], [[x0, y0, z], [x1, y1, z], [x0, y1, z]]], np.float64)
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float64)
    n = np.zeros_like(p)
    n[..., 2] = 1.0
    return p, uv, n


def scene_of(quads, camera, lights, index=None) -> InScene:
    parts = [np.concatenate(a) for a in zip(*quads)]
    mesh = mesh_from_triangles(*parts)
    mesh.material_index = None if index is None else torch.tensor(np.repeat(index, 2))
    return InScene(mesh, camera, lights, {})


CAMERA = PinholeCamera((0.3, 0.2, 4.0), (-0.05, -0.04, -1.0), (0.0, 1.0, 0.0), 40.0)


def test_mesh_uv_is_the_usd_st(mi):  # noqa: F811
    # Exact: si.uv interpolates the stored texcoords; only float32 rounding (1e-5) is allowed.
    p, uv, n = quad(-1.0, 1.0, -0.5, 1.5)
    mesh = ms.make_mesh(mi, "q", p.reshape(-1, 3), n.reshape(-1, 3), uv.reshape(-1, 2),
                        np.arange(6, dtype=np.uint32).reshape(2, 3), diffuse((0.5, 0.5, 0.5)))
    scene = mi.load_dict({"type": "scene", "q": mesh})
    xy = np.random.default_rng(0).uniform([-0.99, -0.49], [0.99, 1.49], (64, 2)).astype(np.float32)
    ray = mi.Ray3f(mi.Point3f(xy[:, 0], xy[:, 1], np.full(64, 2.0, np.float32)), mi.Vector3f(0, 0, -1))
    si = scene.ray_intersect(ray)
    got = np.asarray(si.uv).T
    want = np.stack([(xy[:, 0] + 1) / 2, (xy[:, 1] + 0.5) / 2], -1)
    np.testing.assert_allclose(got, want, atol=1e-5)


def wave(uv: torch.Tensor) -> torch.Tensor:
    """A smooth periodic emission that tells u from 1 - u and v from 1 - v."""
    u, v = uv[:, 0:1], uv[:, 1:2]
    return torch.cat([1 + torch.sin(2 * math.pi * u), 1 + torch.sin(2 * math.pi * v), 0.5 + 0.0 * u], -1)


def test_bitmap_lookup_is_the_projects_texel_grid(mi):  # noqa: F811
    # Mitsuba's bilinear bitmap at uv must be bilinear_periodic of the project's grid (row 0 at v = 1) at the
    # same uv: exact up to float32 (1e-5). Against the smooth function itself, the 64-texel grid's bilinear
    # error, about (2 pi / 64)^2 / 8 ~ 1.2e-3, bounds it (2e-3).
    terms = ms.surface_terms(Lambert(emission_fn=wave), (64, 64))
    grid = torch.from_numpy(terms.emission).permute(2, 0, 1)
    tex = mi.load_dict(ms.emission_emitter(mi, terms)["radiance"])
    uv = np.random.default_rng(1).uniform(0, 1, (256, 2)).astype(np.float32)
    si = _interaction(mi, uv)
    got = np.asarray(tex.eval(si)).T
    np.testing.assert_allclose(got, bilinear_periodic(grid, torch.from_numpy(uv)).numpy(), atol=1e-5)
    np.testing.assert_allclose(got, wave(torch.from_numpy(uv)).numpy(), atol=2e-3)


def _interaction(mi, uv: np.ndarray):  # noqa: F811
    # Local: Dr.Jit, Mitsuba's array library, is present only with Mitsuba (the fixture skips without it).
    import drjit as dr

    si = dr.zeros(mi.SurfaceInteraction3f, len(uv))
    si.uv = mi.Point2f(uv[:, 0], uv[:, 1])
    return si


def test_camera_orientation_matches_the_torch_renderer(mi):  # noqa: F811
    # A red quad lower left and a blue one upper right under one light: a mirrored or upside-down image would
    # swap them. Both renderers average jittered samples with a box over each pixel, so only pixels on an edge
    # may disagree (a 48-pixel image has about 180 edge pixels of 2304: 8% tolerated, 97% + seen to agree).
    red, blue = (0.8, 0.05, 0.05), (0.05, 0.05, 0.8)
    scene = scene_of([quad(-1.0, 0.0, -1.0, 0.2), quad(0.3, 1.1, 0.4, 1.0)], CAMERA,
                     [DirectionalLight((0.2, 0.3, 1.0), 2.0)], index=[0, 1])
    res, spp = 48, 16
    want = render_scene([Lambert(red), Lambert(blue)], scene.geometry, scene.camera, scene.lights, res, spp)
    mscene = mi.load_dict(ms.scene_dict(mi, scene, [ms.Binding(diffuse(red)), ms.Binding(diffuse(blue))], res, spp))
    got = ms.render(mi, mscene, seed=0)
    assert got.shape == want.shape == (res, res, 3)
    for channel in (0, 2):  # red, blue coverage
        a, b = want[..., channel] > 0.05, got[..., channel] > 0.05
        assert a.sum() > 100 and (a == b).mean() > 0.92, (channel, a.sum(), (a == b).mean())
    assert got[: res // 2, res // 2:, 2].sum() > got[res // 2:, : res // 2, 2].sum()  # blue: top right
    ids = ms.pixel_ids(mi, mscene, res)  # centre rays: material 0 red, 1 blue
    assert ((ids == 0) == (want[..., 0] > 0.05)).mean() > 0.92
    assert ((ids == 1) == (want[..., 2] > 0.05)).mean() > 0.92


def test_distant_light_on_a_diffuse_plane(mi):  # noqa: F811
    # A Lambertian plane under a directional light: radiance = albedo / pi * irradiance * cos (exact; float32
    # rounding only, rtol 1e-4). The light is given towards itself, Mitsuba's direction is the opposite.
    albedo, irradiance = (0.2, 0.5, 0.8), (3.0, 2.0, 1.0)
    towards = np.array([0.6, 0.0, 0.8])  # cos = 0.8 to the plane's +z normal
    scene = scene_of([quad(-2, 2, -2, 2)], PinholeCamera((0, 0, 3), (0, 0, -1), (0, 1, 0), 30),
                     [DirectionalLight(tuple(towards), irradiance)])
    got = ms.render(mi, ms.scene_dict(mi, scene, [ms.Binding(diffuse(albedo))], 8, 4))
    want = np.array(albedo) / math.pi * np.array(irradiance) * 0.8
    np.testing.assert_allclose(got.reshape(-1, 3), np.broadcast_to(want, (64, 3)), rtol=1e-4)


def _env():
    rng = np.random.default_rng(2)
    return EnvironmentMap(rng.uniform(0.1, 2.0, (16, 32, 3)).astype(np.float32))


def test_envmap_radiance_matches_the_projects_lookup(mi):  # noqa: F811
    # Mitsuba's envmap eval in direction d (si.wi = -d) against EnvironmentMap.radiance(d): exact (float32,
    # 1e-5) wherever d is more than one Mitsuba texel (1/ENV_UPSAMPLE of a pixel) from the project's pixel
    # borders; everywhere, a blend of neighbouring pixels, so never outside the map's range.
    # Local: Dr.Jit, Mitsuba's array library, is present only with Mitsuba (the fixture skips without it).
    import drjit as dr

    env = _env()
    emitter = mi.load_dict(ms.emitter_dicts(mi, [env])["light_0"])
    d = np.random.default_rng(3).normal(size=(20000, 3))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    si = dr.zeros(mi.SurfaceInteraction3f, len(d))
    si.wi = mi.Vector3f(-d[:, 0], -d[:, 1], -d[:, 2])
    got = np.asarray(emitter.eval(si)).T
    want = env.radiance(torch.from_numpy(d)).numpy()
    uv = direction_to_uv(torch.from_numpy(d)).numpy()
    fu, fv = (uv[:, 0] * env.width) % 1, (uv[:, 1] * env.height) % 1
    m = 1.0 / ms.ENV_UPSAMPLE + 1e-3
    inner = (fu > m) & (fu < 1 - m) & (fv > m) & (fv < 1 - m)
    assert inner.mean() > 0.5
    np.testing.assert_allclose(got[inner], want[inner], atol=1e-5)
    assert got.min() >= env.image.min().item() - 1e-6 and got.max() <= env.image.max().item() + 1e-6


def test_envmap_irradiance_on_a_diffuse_plane(mi):  # noqa: F811
    # A white-ish Lambertian plane facing +y under the environment alone: its radiance is albedo / pi times the
    # irradiance from the upper hemisphere (EnvironmentMap.irradiance, a midpoint rule over the pixels). The
    # Mitsuba render is a Monte Carlo estimate (64 spp x 256 pixels averaged: standard error well under 1%),
    # and near pixel borders its bilinear lookup blends neighbours (a few tenths of a percent on this map):
    # 2% relative.
    env = _env()
    p, uv, n = quad(-2, 2, -2, 2)
    p = p[..., [0, 2, 1]] * np.array([1, 1, -1])  # into the xz plane, normal +y (right-handed: x, -z)
    n = np.zeros_like(p)
    n[..., 1] = 1.0
    mesh = mesh_from_triangles(p, uv, n)
    scene = InScene(mesh, PinholeCamera((0, 3, 0), (0, -1, 0), (0, 0, -1), 20), [env], {})
    albedo = 0.5
    got = ms.render(mi, ms.scene_dict(mi, scene, [ms.Binding(diffuse((albedo,) * 3))], 16, 64, max_depth=2))
    want = albedo / math.pi * env.irradiance((0.0, 1.0, 0.0)).numpy()
    np.testing.assert_allclose(got.reshape(-1, 3).mean(0), want, rtol=0.02)


def band(uv: torch.Tensor) -> torch.Tensor:
    """A cut-out that is there above v = 0.6 and left of u = 0.3 (an upside-down L)."""
    return ((uv[:, 1] > 0.6) | (uv[:, 0] < 0.3)).float()


@pytest.mark.slow
def test_emission_and_cutout_match_the_torch_renderer(mi):  # noqa: F811
    # An emissive quad (the wave pattern) behind a black cut-out quad (an upside-down L of surface). Emission
    # and opacity go through the mesh's uv, the bitmaps' flip and the mask; the torch renderer shows the same.
    # Inside the surfaces the two differ by the emission grid's bilinear error (2e-3); on the quads' and the
    # cut-out's edges by sampling noise (16 jittered samples per pixel in both, box filtered: a half-covered
    # pixel's cover varies by +-12%, times radiance up to 2) and by at most a fine texel's shift of the cut-out's
    # edge. So: the image means agree within 2% (the edge noise averages out over 1600 pixels; 0.3% seen),
    # and 85% of the pixels (all but the edges; 88% seen) within 0.05.
    res, spp = 40, 16
    front = Lambert((0.0, 0.0, 0.0), opacity_fn=band)
    back = Lambert((0.0, 0.0, 0.0), emission_fn=wave)
    scene = scene_of([quad(-1.0, 1.0, -1.0, 1.0, 0.0), quad(-0.8, 0.8, -0.8, 0.8, 0.5)],
                     PinholeCamera((0, 0, 4), (0, 0, -1), (0, 1, 0), 35), [], index=[0, 1])
    want = render_scene([back, front], scene.geometry, scene.camera, scene.lights, res, spp)
    bindings = [ms.Binding(diffuse((0, 0, 0)), ms.surface_terms(back, (64, 64))),
                ms.Binding(diffuse((0, 0, 0)), ms.surface_terms(front, (64, 64)))]
    assert bindings[1].surface.cutout and bindings[1].surface.emission is None
    got = ms.render(mi, ms.scene_dict(mi, scene, bindings, res, spp, max_depth=3))
    np.testing.assert_allclose(got.mean((0, 1)), want.mean((0, 1)), rtol=0.02)
    assert (np.abs(got - want).max(-1) < 0.05).mean() > 0.85
    # the cut-out's solid top band is black in both, the hole below it shows the emission: v up the image
    row_band, row_hole, col = int(res * 0.3), int(res * 0.65), int(res * 0.6)
    assert got[row_band, col].sum() == 0 and want[row_band, col].sum() == 0
    assert got[row_hole, col].sum() > 0.5 and want[row_hole, col].sum() > 0.5


def test_constant_surface_terms_are_plain_values(mi):  # noqa: F811
    # Uniform emission and a blend opacity become plain values (no bitmap); emission is weighted by opacity.
    mat = Lambert(emission_fn=lambda uv: torch.tensor([[2.0, 1.0, 0.5]]).expand(len(uv), 3),
                  opacity_fn=lambda uv: torch.full((len(uv),), 0.25))
    mat.alpha_cutoff = None  # a blend
    terms = ms.surface_terms(mat, (8, 8))
    assert terms.opacity == pytest.approx(0.25) and not terms.cutout
    assert terms.emission == pytest.approx((0.5, 0.25, 0.125))
    assert ms.masked_bsdf(mi, diffuse((1, 1, 1)), terms)["opacity"] == pytest.approx(0.25)
    assert ms.surface_terms(Lambert(), (8, 8)).empty
