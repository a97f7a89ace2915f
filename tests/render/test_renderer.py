"""Evaluation renderer and image errors: ``render_scene`` with its cameras (perspective,
orthographic), geometry (sphere, plane, OBJ mesh), lights (directional, environment maps) and
ray-cone levels of detail; ``render``/``compare``'s orthographic sphere on top of it; the
``mtlx2neural render`` command. Seeded, a few seconds in all."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import SIMPLE_MTLX, shared_path

import mtlx2neural as m2n
from mtlx2neural.baseline.analytic_model import AnalyticMaterial
from mtlx2neural.cli import main
from mtlx2neural.contract import as_point
from mtlx2neural.model.neural_material import NeuralMaterial
from mtlx2neural.render.geometry import (
    Camera,
    OrthographicCamera,
    Plane,
    Sphere,
    load_obj,
    ray_cone_lod,
)
from mtlx2neural.render.lighting import (
    DirectionalLight,
    EnvironmentMap,
    uv_to_direction,
)
from mtlx2neural.render.renderer import (
    VIEWS,
    View,
    compare,
    compare_many,
    image_errors,
    render,
    render_scene,
    sample_footprint_scale,
)

SAMPLE = Path(__file__).resolve().parents[2] / "samples" / "layered_spheres.usda"


def test_sphere_render_and_flip():
    ref = m2n.load_reference(SAMPLE, "/World/Looks/Plastic")
    img = render(ref, VIEWS[0], res=48, spp=2)
    assert img.shape == (48, 48, 3) and np.isfinite(img).all()
    assert img[0, 0].sum() == 0 and img[24, 24].sum() > 0  # background corner vs lit centre
    same = image_errors(img, img)
    assert same["flip"] == 0.0 and same["mae"] == 0.0
    dark = image_errors(img, img * 0.5)
    assert dark["flip"] > 0.05 and dark["relmse"] > 0.0  # halving the brightness is clearly visible


class _Eval:
    """A test material made of an ``eval`` function of (wi, wo, ShadingPoint): all the renderers ask of
    the material they draw (sampling comes from their ``sampler``)."""

    def __init__(self, fn):
        self.fn = fn

    def eval(self, wi, wo, at=None):
        return self.fn(wi, wo, as_point(at))


_ones = _Eval(lambda wi, wo, at: torch.ones(len(wi), 3))
# A material whose value is the level of detail it was asked for (grey).
_lod_echo = _Eval(lambda wi, wo, at: at.lod[:, None].expand(-1, 3).clone())


@pytest.mark.parametrize("spp,shift", [(1, 0.0), (4, 1.0), (16, 2.0), (64, 3.0), (256, 3.0)])
def test_each_sample_filters_its_share_of_the_pixel(spp, shift):
    """Both renderers look textures up at the footprint of one of ``spp`` samples, not of the
    whole pixel: the level of detail drops by log2 sqrt(spp), at most by 3 (pbrt-v4's 1/8
    floor). A 16k-texel texture keeps every level above 3, so nothing is clamped at 0."""
    assert sample_footprint_scale(spp) == max(0.125, 1 / math.sqrt(spp))
    texels = (16384, 16384)
    k = VIEWS[0].intensity
    pixel = render(_lod_echo, VIEWS[0], res=16, spp=spp, texels=texels, footprint=1.0) / k
    sample = render(_lod_echo, VIEWS[0], res=16, spp=spp, texels=texels) / k
    hit = render(_ones, VIEWS[0], res=16, spp=spp, texels=texels)[..., 0] / k > 1 - 1e-5  # every sample hit
    assert hit.mean() > 0.4
    # float32 log2 of the same footprints: agreement to 1e-4 levels.
    assert np.allclose(pixel[hit] - sample[hit], shift, atol=1e-4)
    cam = Camera(0, 90)
    light = [DirectionalLight((0.0, 1.0, 1.0), 1.0)]
    pixel = render_scene(_lod_echo, Plane(), cam, light, res=16, spp=spp, texels=texels, footprint=1.0)
    sample = render_scene(_lod_echo, Plane(), cam, light, res=16, spp=spp, texels=texels)
    hit = render_scene(_ones, Plane(), cam, light, res=16, spp=spp, texels=texels)[..., 0] > 1 - 1e-5
    assert hit.mean() > 0.3
    # render_scene divides by spp after summing per pass: float32 sums of spp values ~7.
    assert np.allclose(pixel[hit] - sample[hit], shift, atol=1e-3)


# ----------------------------------------------------------------------------- render_scene, geometry, lighting

ALBEDO = torch.tensor([0.8, 0.5, 0.2])


def _lambert(wi, wo, at=None):
    """A constant-albedo diffuse material's f*cos: albedo / pi * cos(wo)."""
    return ALBEDO / math.pi * wo[:, 2:3].clamp_min(0)


lambert = _Eval(_lambert)


def _camera_light(azimuth: float, elevation: float) -> tuple:
    """The direction towards a camera at ``azimuth``/``elevation`` (degrees): a light there lights every
    pixel the camera sees (the renderer skips pixels whose light is below the horizon)."""
    az, el = math.radians(azimuth), math.radians(elevation)
    return (math.sin(az) * math.cos(el), math.sin(el), math.cos(az) * math.cos(el))


def test_orthographic_rays_are_parallel_and_cover_the_sphere():
    """Every ray runs along -d from its own origin; the unit sphere's disc covers pi / (4 * 1.1^2) of the
    +-1.1 image. 64x64 jittered pixels: ~180 straddle the silhouette, each hit or missed at random, so the
    fraction's standard deviation is ~0.002; the test allows 0.01."""
    cam = OrthographicCamera(30.0, 20.0)
    rays = cam.rays(64, *Sphere().bounds(), torch.Generator().manual_seed(0))
    d, right, up = cam.basis()
    assert rays.origin.shape == (64 * 64, 3) and rays.spread == 0.0
    assert rays.width == pytest.approx(2.2 / 64)
    assert torch.allclose(rays.dirs, -d.expand(64 * 64, 3))
    # origins fill the image plane 2 radii in front of the centre, within +-1.1 in both axes
    assert torch.allclose(rays.origin @ d, torch.full((64 * 64,), 2.0))
    assert float((rays.origin @ right).abs().max()) <= 1.1 and float((rays.origin @ up).abs().max()) <= 1.1
    hits = Sphere().intersect(rays)
    assert abs(float(hits.mask.float().mean()) - math.pi / (4 * 1.1 ** 2)) < 0.01
    assert torch.allclose(hits.t[hits.mask], 2 - (1 - (rays.origin[hits.mask] @ right) ** 2
                                                  - (rays.origin[hits.mask] @ up) ** 2).sqrt(), atol=1e-5)


def test_orthographic_sphere_uv_follows_the_spherical_map():
    """At every hit the uv is the analytic one of the point under the pixel: p = x right + y up +
    sqrt(1 - x^2 - y^2) d for the ray's image-plane (x, y); u = 0.5 + atan2(p.x, p.z) / 2pi, v =
    acos(-p.y) / pi; the tangent is along +u, (p.z, 0, -p.x) normalised (float32: 1e-5)."""
    cam = OrthographicCamera(200.0, -10.0)
    rays = cam.rays(24, *Sphere().bounds(), torch.Generator().manual_seed(1))
    hits = Sphere().intersect(rays)
    d, right, up = cam.basis()
    m = hits.mask
    x, y = rays.origin[m] @ right, rays.origin[m] @ up
    p = x[:, None] * right + y[:, None] * up + (1 - x * x - y * y).clamp_min(0).sqrt()[:, None] * d
    u = 0.5 + torch.atan2(p[:, 0], p[:, 2]) / (2 * math.pi)
    v = torch.acos(-p[:, 1]) / math.pi
    assert torch.allclose(hits.uv[m], torch.stack([u, v], -1), atol=1e-5)
    t = torch.nn.functional.normalize(torch.stack([p[:, 2], torch.zeros_like(u), -p[:, 0]], -1), dim=-1)
    assert torch.allclose(hits.tangent[m], t, atol=1e-5)
    assert torch.allclose(hits.normal[m], p, atol=1e-5)


def test_orthographic_lod_is_flat_at_the_centre_and_grows_to_the_silhouette():
    """Seen from the equator, the image centre is the point (0, 0, 1): cos 1, |dP/du| = 2 pi, |dP/dv| =
    pi, so one pixel (2.2 / res wide) covers 2.2 / res * w / (2 pi) texels along u and 2.2 / res * h / pi
    along v: lod = log2 of their geometric mean. The jitter moves the point by < 1 pixel (cos > 0.999,
    < 0.002 levels); the test allows 0.01. Along the middle row one axis grows as 1 / cos towards the
    silhouette, so the level grows as 0.5 log2(1 / cos)."""
    res, texels = 64, (1024, 1024)
    view = View(0.0, 0.0, _camera_light(0.0, 0.0), 1.0)
    lod = render(_lod_echo, view, res=res, spp=1, texels=texels, footprint=1.0)[..., 0]
    centre = lod[30:34, 30:34]
    pixel = 2.2 / res
    assert np.allclose(centre, math.log2(math.sqrt(pixel * 1024 / (2 * math.pi) * pixel * 1024 / math.pi)),
                       atol=0.01)
    row = lod[32, 32:60:4]  # x from 0 to ~0.85: 1 / cos grows from 1 to ~1.9, 0.5 log2 of it to ~0.46
    assert np.all(np.diff(row) > 0), row
    assert 0.3 < row[-1] - row[0] < 0.6


def test_render_of_a_lambertian_sphere_is_cos_albedo_intensity():
    """At the centre pixel of a 101-pixel view from the equator the normal is (0, 0, 1) up to the pixel's
    jitter (< 0.016 rad): the image is albedo / pi * cos(light) * intensity within 1 % (the cosine's
    slope times that tilt is < 0.8 %)."""
    light = (0.3, 0.5, 1.0)
    img = render(lambert, View(0.0, 0.0, light, 2.0), res=101, spp=1)
    cos = 1.0 / float(np.linalg.norm(light))
    assert np.allclose(img[50, 50], (ALBEDO / math.pi).numpy() * cos * 2.0, rtol=0.01)
    assert img[0, 0].sum() == 0  # a corner misses the sphere


def test_lambertian_plane_under_a_directional_light_is_exact():
    light = DirectionalLight((0.0, 1.0, 1.0), 2.0)
    img = render_scene(lambert, Plane(), Camera(0, 90), [light], res=24, spp=1)  # 1 spp: no partial edge pixels
    hit = img.sum(-1) > 0
    assert hit.mean() > 0.3
    expected = (ALBEDO / math.pi * 2.0 / math.sqrt(2)).numpy()
    assert np.allclose(img[hit], expected, rtol=1e-5)


def test_lambertian_plane_under_the_sky_matches_its_irradiance():
    """Pixel radiance = albedo / pi * E, E integrated from the map by quadrature; the Monte Carlo
    mean over 32x32 pixels x 16 light samples agrees within 2 % (its relative error is ~0.5 %)."""
    sky = EnvironmentMap.sky()
    img = render_scene(lambert, Plane(), Camera(0, 90, distance=1.5), [sky], res=32, spp=16, seed=3)
    assert (img.sum(-1) > 0).all()  # the plane fills the frame: no partially covered pixels
    expected = (ALBEDO / math.pi * sky.irradiance((0.0, 1.0, 0.0))).numpy()
    assert np.allclose(img.reshape(-1, 3).mean(0), expected, rtol=0.02)
    # Every pixel is an unbiased 16-sample estimate: none is wildly off.
    assert np.all(np.abs(img / expected - 1) < 1.0)


def test_environment_pdf_integrates_to_one_and_matches_sampling():
    sky = EnvironmentMap.sky()
    # Midpoint quadrature over 4x4 points per pixel: exact up to sin(theta) varying inside a pixel.
    n = 4
    h, w = sky.height * n, sky.width * n
    uv = torch.stack(torch.meshgrid((torch.arange(w) + 0.5) / w, (torch.arange(h) + 0.5) / h, indexing="xy"), -1)
    uv = uv.reshape(-1, 2)
    dw = (2 * math.pi / w) * (math.pi / h) * torch.sin(math.pi * uv[:, 1])
    assert abs(float((sky.pdf(uv_to_direction(uv)) * dw).sum()) - 1) < 1e-3
    # Monte Carlo with uniform directions on the sphere: 4 pi E[pdf] = 1 within 5 % (the sun makes it noisy).
    g = torch.Generator().manual_seed(0)
    d = torch.nn.functional.normalize(torch.randn(400_000, 3, generator=g), dim=-1)
    assert abs(float(sky.pdf(d).mean()) * 4 * math.pi - 1) < 0.05
    # Sampling: the returned pdf is pdf(d), the weight is L / pdf, and E[1 / pdf] = 4 pi within 2 %.
    ds, weight, pdf = sky.sample(torch.rand(200_000, 3, generator=g))
    # (a direction on a pixel border may round to the neighbouring pixel: allow 0.1 % of them)
    assert ((sky.pdf(ds) - pdf).abs() <= 1e-3 * pdf).float().mean() > 0.999
    assert ((weight * pdf[:, None] - sky.radiance(ds)).abs() <= 1e-3 * sky.radiance(ds)).all(-1).float().mean() > 0.999
    assert abs(float((1 / pdf).mean()) / (4 * math.pi) - 1) < 0.02
    # Bright pixels are sampled more: the sun direction gets far more samples than its solid angle.
    az, el = math.radians(30), math.radians(45)  # EnvironmentMap.sky's default sun
    sun = torch.tensor([math.sin(az) * math.cos(el), math.sin(el), math.cos(az) * math.cos(el)])
    near_sun = (ds @ sun) > math.cos(math.radians(6))
    assert near_sun.float().mean() > 0.2


class _HemisphereLambert:
    """The Lambertian material above with cosine-weighted or uniform hemisphere sampling (local frame):
    a sampler for render_scene, with the Material methods it uses (sample, pdf) and eval."""

    def __init__(self, cosine: bool):
        self.cosine = cosine

    def eval(self, wi, wo, at=None):
        return _lambert(wi, wo)

    def pdf(self, wi, wo, at=None):
        z = wo[:, 2].clamp_min(0)
        return torch.where(wo[:, 2] > 0, z / math.pi if self.cosine else torch.full_like(z, 0.5 / math.pi),
                           torch.zeros_like(z))

    def sample(self, wi, u, at=None):
        phi = 2 * math.pi * u[:, 0]
        z = (1 - u[:, 1]).sqrt() if self.cosine else 1 - u[:, 1]
        r = (1 - z * z).clamp_min(0).sqrt()
        wo = torch.stack([r * phi.cos(), r * phi.sin(), z], -1)
        pdf = self.pdf(wi, wo)
        return wo, self.eval(wi, wo) / pdf.clamp_min(1e-30)[:, None], pdf


def test_mis_with_any_sampler_keeps_the_lambertian_plane_exact():
    """Light + sampler directions with balance-heuristic weights: the plane's mean radiance is still
    albedo / pi * E for a well-matched (cosine) and a mismatched (uniform) sampler, within 2 % as the
    light-only test above (the two weights must sum to one, or the mean is off by far more)."""
    sky = EnvironmentMap.sky()
    expected = (ALBEDO / math.pi * sky.irradiance((0.0, 1.0, 0.0))).numpy()
    for cosine in (True, False):
        img = render_scene(lambert, Plane(), Camera(0, 90, distance=1.5), [sky], res=32, spp=16, seed=3,
                           sampler=_HemisphereLambert(cosine))
        assert np.isfinite(img).all()
        assert np.allclose(img.reshape(-1, 3).mean(0), expected, rtol=0.02), cosine


def test_mis_with_the_reference_sampler_tames_a_clear_coat_under_the_sky():
    """The CarPaint's roughness-0.08 coat reflects the sky: light samples alone find that lobe by
    chance. On a plane that fills the frame (no silhouette noise), two seeds' renders differ far less
    with the reference's sampler (measured 4.5x less at 4 spp; the test asks 2.5x). Common random
    numbers still hold: half the material renders at exactly half. (That the weights keep the
    estimate unbiased is the Lambertian test above; the reference's pdf is chi-square tested.)"""
    ref = m2n.load_reference(SAMPLE, "/World/Looks/CarPaint")
    sky = EnvironmentMap.sky()
    cam = Camera(0, 60, distance=1.5)
    smp = ref  # the reference samples its own lobe mixture (Material.sample / pdf)

    def draw(seed, sampler=None, material=None):
        material = ref if material is None else material
        return render_scene(material, Plane(), cam, [sky], res=24, spp=4, seed=seed, sampler=sampler)

    def noise(a, b):
        return float(np.abs(a - b).mean() / a.mean())

    mis = draw(1, smp)
    assert np.isfinite(mis).all() and (mis.sum(-1) > 0).all()
    assert noise(mis, draw(2, smp)) < noise(draw(1), draw(2)) / 2.5
    half = draw(1, smp, _Eval(lambda wi, wo, at: 0.5 * ref.eval(wi, wo, at)))
    assert np.allclose(half, 0.5 * mis, rtol=1e-5, atol=1e-7)


def test_passes_shaded_together_equal_pass_by_pass(monkeypatch):
    """render_scene shades the hits of several passes in one call (PASS_BATCH_POINTS): the same rays,
    levels, light and sampler directions as one call per pass, so the image is the same. Tolerance 1e-6
    relative: only the order of the float32 sums over the passes differs."""
    from mtlx2neural.render import renderer

    ref = m2n.load_reference(SAMPLE, "/World/Looks/CarPaint")
    sky = EnvironmentMap.sky()

    def draw():
        return render_scene(ref, Sphere(), Camera(30, 20, distance=4.0), [sky, DirectionalLight((0.4, 0.7, 0.6), 3.0)],
                            res=24, spp=8, seed=5, sampler=ref)

    together = draw()
    monkeypatch.setattr(renderer, "PASS_BATCH_POINTS", 1)
    alone = draw()
    assert (together.sum(-1) > 0).mean() > 0.3
    np.testing.assert_allclose(together, alone, rtol=1e-6, atol=1e-7)


def test_hdr_environment_from_the_materialx_resources():
    """The MaterialX resources' (irradiance) lat-long maps load through OpenImageIO, their pdf
    integrates to 1, and a Lambertian plane under one matches its irradiance within 3 % (std ~0.8 %)."""
    env = EnvironmentMap.from_file(shared_path("materialx", "resources", "Lights", "irradiance",
                                               "san_giuseppe_bridge.hdr"))
    assert (env.height, env.width) == (128, 256) and float(env.image.min()) >= 0
    uv = torch.stack(torch.meshgrid((torch.arange(512) + 0.5) / 512, (torch.arange(256) + 0.5) / 256,
                                    indexing="xy"), -1).reshape(-1, 2)
    dw = (2 * math.pi / 512) * (math.pi / 256) * torch.sin(math.pi * uv[:, 1])
    assert abs(float((env.pdf(uv_to_direction(uv)) * dw).sum()) - 1) < 1e-3
    img = render_scene(lambert, Plane(), Camera(0, 90, distance=1.5), [env], res=32, spp=16, seed=3)
    expected = (ALBEDO / math.pi * env.irradiance((0.0, 1.0, 0.0))).numpy()
    assert np.allclose(img.reshape(-1, 3).mean(0), expected, rtol=0.03)


def test_ray_cone_lod_grows_with_distance_and_grazing_angle():
    def centre_lod(camera):
        geo = Plane()
        rays = camera.rays(33, *geo.bounds(), torch.Generator().manual_seed(0))
        hits = geo.intersect(rays)
        lod = ray_cone_lod(hits, rays.spread, (1024, 1024))
        assert bool(hits.mask[16 * 33 + 16])
        return float(lod[16 * 33 + 16]), hits

    near, hits = centre_lod(Camera(0, 80, distance=3))
    far, _ = centre_lod(Camera(0, 80, distance=6))
    grazing, _ = centre_lod(Camera(0, 20, distance=3))
    assert abs((far - near) - 1.0) < 0.05  # twice the distance: one level coarser
    # Grazing stretches one footprint axis by 1/cos; the level follows the geometric mean of the axes
    # (the paper's isotropic footprint), so it rises by half the log2 of the stretch.
    assert abs((grazing - near) - 0.5 * math.log2(math.sin(math.radians(80)) / math.sin(math.radians(20)))) < 0.05
    assert float(ray_cone_lod(hits, 1e-6, (4, 4)).min()) == 0.0  # clamped at the finest level
    # Frames are orthonormal and right-handed; uv lies in [0, tiles].
    m = hits.mask
    assert torch.allclose(torch.linalg.cross(hits.tangent[m], hits.bitangent[m], dim=-1), hits.normal[m], atol=1e-5)
    assert float(hits.uv[m].min()) >= 0 and float(hits.uv[m].max()) <= 2


def test_same_seed_same_image_and_common_random_numbers():
    sky = EnvironmentMap.sky()
    half = _Eval(lambda wi, wo, at: 0.5 * _lambert(wi, wo))

    a = render_scene(lambert, Sphere(), Camera(40, 20), [sky], res=24, spp=3, seed=5)
    assert np.array_equal(a, render_scene(lambert, Sphere(), Camera(40, 20), [sky], res=24, spp=3, seed=5))
    assert not np.array_equal(a, render_scene(lambert, Sphere(), Camera(40, 20), [sky], res=24, spp=3, seed=6))
    # Same seed: a material at half the albedo renders at exactly half, pixel by pixel (no noise difference).
    assert np.allclose(render_scene(half, Sphere(), Camera(40, 20), [sky], res=24, spp=3, seed=5), 0.5 * a,
                       rtol=1e-6, atol=1e-7)


def test_compare_on_scene_geometry():
    ref = m2n.load_reference(SAMPLE, "/World/Looks/Plastic")
    model = NeuralMaterial((1, 1), 0).train(False)
    out = compare(ref, model, (1, 1), views=VIEWS[:1], res=16, spp=2, geometry=Plane(),
                  lights=[EnvironmentMap.sky()])
    assert out[0]["reference"].shape == (16, 16, 3) and np.isfinite(out[0]["flip"])
    assert out[0]["neural"].shape == (16, 16, 3)  # the default label names the model's render


def test_compare_many_names_each_render_after_its_material():
    """One reference render per view, shared; each material's render under its own label (the analytic
    baseline under "analytic", not "neural"); a label that clashes with compare's keys is refused."""
    ref = m2n.load_reference(SAMPLE, "/World/Looks/Plastic")
    torch.manual_seed(0)
    models = {"neural": NeuralMaterial((1, 1), 0).train(False), "analytic": AnalyticMaterial().train(False)}
    out = compare_many(ref, models, (1, 1), views=VIEWS[:2], res=12, spp=1)
    assert set(out) == {"neural", "analytic"}
    for label, per_view in out.items():
        assert len(per_view) == 2
        for e in per_view:
            assert set(e) == {"view", "reference", label, "flip", "flip_map", "mae", "relmse"}
    assert np.array_equal(out["neural"][0]["reference"], out["analytic"][0]["reference"])
    assert not np.array_equal(out["neural"][0]["neural"], out["analytic"][0]["analytic"])
    # the same render as compare() gives for that material alone (same seed per view)
    alone = compare(ref, models["analytic"], (1, 1), views=VIEWS[:1], res=12, spp=1, label="analytic")
    assert np.array_equal(alone[0]["analytic"], out["analytic"][0]["analytic"])
    with pytest.raises(ValueError, match="clash"):
        compare_many(ref, {"flip": models["neural"]}, (1, 1), views=VIEWS[:1], res=4, spp=1)


def test_teapot_rasterises_exactly_with_plausible_coverage():
    mesh = load_obj(shared_path("materialx", "resources", "Geometry", "teapot.obj"))
    assert len(mesh.triangles) > 20_000 and bool((mesh.uvs.max(0).values > 0.9).all())  # it has vt
    every = torch.arange(len(mesh.triangles))
    # the perspective camera's shared origin and the orthographic camera's one origin per ray
    for cam in (Camera(123, -30, 2.5, 40), OrthographicCamera(123, -30, 0.8)):
        rays = cam.rays(16, *mesh.bounds(), torch.Generator().manual_seed(3))
        hits = mesh.intersect(rays)
        best = torch.full((len(rays.dirs),), math.inf)  # brute force over every triangle
        for i in range(len(rays.dirs)):
            o = rays.origin if rays.origin.dim() == 1 else rays.origin[i]
            t, _, _ = mesh._ray_triangle(o, rays.dirs[i].expand(len(every), 3), every)
            best[i] = torch.where(t > 0, t, math.inf).min()
        assert 0.1 < float(hits.mask.float().mean()) < 0.9, cam
        assert torch.equal(torch.isfinite(best), hits.mask), cam
        assert torch.allclose(best[hits.mask], hits.t[hits.mask], rtol=1e-6), cam
    img = render_scene(lambert, mesh, Camera(30, 20), [EnvironmentMap.sky()], res=48, spp=2)
    coverage = (img.sum(-1) > 0).mean()
    assert 0.25 < coverage < 0.6, coverage
    assert np.isfinite(img).all() and img[24, 24].sum() > 0


def test_cli_render_writes_exr_and_rejects_missing_input(tmp_path, capsys):
    import OpenImageIO as oiio

    from mtlx2neural.report.views import default_checkpoint
    from mtlx2neural.scene import find_material

    asset = tmp_path / "red.mtlx"
    asset.write_text(SIMPLE_MTLX)
    out = tmp_path / "red.exr"
    common = ["--res", "12", "--spp", "2", "-o", str(out)]
    assert main(["render", str(asset), "--material", "Red", "--geometry", "plane", *common]) == 0
    img = oiio.ImageBuf(str(out)).get_pixels(oiio.FLOAT)
    assert img.shape == (12, 12, 3) and img.max() > 0 and (tmp_path / "red.png").is_file()
    capsys.readouterr()
    # Neural: the default checkpoint location is the convert output folder; missing -> exit 2.
    ck = default_checkpoint(asset, find_material(asset, "Red").name)
    out.unlink()
    assert main(["render", str(asset), "--model", "neural", *common]) == 2
    err = capsys.readouterr().err
    assert re.search(re.escape(str(ck)), err) and "Traceback" not in err and not out.exists()
    ck.parent.mkdir(parents=True)
    torch.save({"model": NeuralMaterial((1, 1), 0).state_dict(), "config": {}}, ck)
    assert main(["render", str(asset), "--model", "neural", *common]) == 0
    assert oiio.ImageBuf(str(out)).get_pixels(oiio.FLOAT).shape == (12, 12, 3)
    capsys.readouterr()
    for bad, what in ((["--material", "Blue"], "Blue"), (["--geometry", str(tmp_path / "no.obj")], "no.obj"),
                      (["--env", str(tmp_path / "no.hdr")], "no.hdr")):
        assert main(["render", str(asset), *bad, *common]) == 2
        assert what in capsys.readouterr().err


def test_render_cli_mis_with_the_models_own_sampler(tmp_path):
    """``render_asset(mis="own")`` adds the model's own BSDF samples: on the CarPaint's sharp coat
    under the sky, two seeds differ far less than with light samples alone (the comparison test
    above measured 4.5x with the reference's sampler; this asks 2x at 4 spp; the estimator's bias is
    tested on the Lambertian plane above: at 4 spp even the means of two seeds differ by 18%). A neural
    model renders with its learned proxy as the sampler; a bad --mis is an input error."""
    from mtlx2neural.errors import InputError
    from mtlx2neural.report.views import render_asset

    asset = SAMPLE
    imgs = {}
    for mis in ("own", "none"):
        for seed in (1, 2):
            out = tmp_path / f"{mis}{seed}.exr"
            s = render_asset(asset, out, "CarPaint", res=24, spp=4, seed=seed, mis=mis)
            assert s["mis"] == mis
            imgs[mis, seed] = oiio_pixels(out)
    noise = {m: float(np.abs(imgs[m, 1] - imgs[m, 2]).mean()) for m in ("own", "none")}
    assert noise["own"] * 2 < noise["none"], noise
    ck = tmp_path / "ck" / "checkpoint.pt"
    ck.parent.mkdir()
    torch.manual_seed(0)
    torch.save({"model": NeuralMaterial((1, 1), 0).state_dict(), "config": {"analytic_cosine": True}}, ck)
    s = render_asset(asset, tmp_path / "n.exr", "CarPaint", model="neural", checkpoint=ck, res=12, spp=2)
    assert s["mis"] == "own" and np.isfinite(oiio_pixels(tmp_path / "n.exr")).all()
    with pytest.raises(InputError, match="--mis"):
        render_asset(asset, tmp_path / "x.exr", "CarPaint", mis="both")


def oiio_pixels(path) -> np.ndarray:
    import OpenImageIO as oiio

    return oiio.ImageBuf(str(path)).get_pixels(oiio.FLOAT)
