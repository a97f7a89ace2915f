"""A small batched torch renderer for evaluation: one direct-lighting loop, :func:`render_scene`,
for every camera, geometry and light of :mod:`.geometry` and :mod:`.lighting`.

Every material here is a :class:`~mtlx2neural.contract.Material` (the reference, the neural and
the analytic one alike): the renderer calls only its ``eval`` (and, for multiple importance
sampling, a material's ``sample`` and ``pdf``) with directions in the local shading frame (z the
normal, x the tangent, ``wi`` to the camera, ``wo`` to the light) and a
:class:`~mtlx2neural.contract.ShadingPoint` (``uv``, ``lod``, ``u_level``) per hit.

:func:`render_scene` takes a camera (perspective :class:`.geometry.Camera` or
:class:`.geometry.OrthographicCamera`), a geometry (sphere, plane, OBJ mesh) and lights
(directional lights, importance-sampled environment maps). Each of ``spp`` passes jitters every
pixel's ray; a pixel's colour is the mean over passes of ``material.eval(wi, wo, at) * intensity``
(f*cos, the cosine included) per directional light, plus one light sample (and optionally one
BSDF sample, combined by MIS) per environment map. The level of detail comes from the ray cone
(:func:`.geometry.ray_cone_lod`: a pinhole's cone spreads from the eye, an orthographic beam keeps
one pixel's width), in texels of the material's finest level, scaled to the footprint of one of the
``spp`` samples (:func:`sample_footprint_scale`).

:func:`render` is the evaluation view: the unit sphere (y up; u around the y axis, v from the south
pole, the tangent along increasing u) seen orthographically (+-1.1 radii) from a :class:`View`'s
azimuth/elevation under its directional light; a thin wrapper over :func:`render_scene`.

``compare`` renders several fixed views of a reference and another material with the same seeds
and reports HDR FLIP (flip-evaluator), mean absolute error and relative MSE per view; each render
is stored under the name of the material it shows (``"reference"``, and the label given to the
other, e.g. ``"neural"`` or ``"analytic"``). By default the views are :func:`render`'s;
``compare(..., geometry=, lights=)`` uses a perspective camera on any geometry and lights.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import OpenImageIO as oiio
import torch

from mtlx2neural.contract import Material, ShadingPoint
from mtlx2neural.render.flip import hdr_flip
from mtlx2neural.render.geometry import (
    Camera,
    Hits,
    OrthographicCamera,
    Sphere,
    ray_cone_lod,
)
from mtlx2neural.render.lighting import DirectionalLight, EnvironmentMap


@dataclass(frozen=True)
class View:
    """Camera azimuth/elevation (degrees) and a directional light (direction towards the light, world)."""

    azimuth: float
    elevation: float
    light: tuple = (0.4, 0.7, 0.6)
    intensity: float = 3.0


VIEWS = (View(0.0, 15.0), View(70.0, 35.0, (-0.6, 0.5, 0.6)), View(200.0, -10.0, (0.2, 0.2, -1.0)))


def sample_footprint_scale(spp: int) -> float:
    """The share of a pixel's footprint that one of ``spp`` jittered samples filters over:
    max(1/8, 1/sqrt(spp)), pbrt-v4's scale of camera-ray differentials.

    The jittered samples already average the pixel (a box), so a prefiltered material
    looked up at the whole pixel's level of detail is filtered twice and renders blurrier
    than the point-sampled reference it is compared with (the GlazedCeramic's grout lines,
    docs/history/BENCHMARKS-2026-12-01.md); the spacing between samples is what each lookup has to filter. 1 at
    1 spp (a real-time renderer's single lookup), 1/8 from 64 spp on."""
    return max(0.125, 1.0 / math.sqrt(max(spp, 1)))


def render(material: Material, view: View, res: int = 96, spp: int = 4, texels: tuple[int, int] = (1, 1),
           seed: int = 0, footprint: float | None = None) -> np.ndarray:
    """[res, res, 3] float32 linear HDR image of ``material.eval(wi, wo, ShadingPoint(uv, lod, u_level))``
    (f*cos, local frame) on the unit sphere under ``view``'s directional light, seen by an
    :class:`.geometry.OrthographicCamera` at ``view``'s azimuth/elevation (the image spans +-1.1).

    :func:`render_scene` with that camera, :class:`.geometry.Sphere` and one
    :class:`.lighting.DirectionalLight`: ``lod`` is log2 of ``footprint`` times one pixel's width
    on the surface (the orthographic beam's, divided by the cosine) in texels of ``texels`` (h, w);
    ``footprint`` defaults to :func:`sample_footprint_scale` of ``spp``."""
    return render_scene(material, Sphere(), OrthographicCamera(view.azimuth, view.elevation),
                        [DirectionalLight(view.light, view.intensity)], res, spp, texels, seed,
                        footprint=footprint)


def render_scene(material: Material, geometry, camera, lights, res: int = 128, spp: int = 16,
                 texels: tuple[int, int] = (1, 1), seed: int = 0, sampler: Material | None = None,
                 footprint: float | None = None) -> np.ndarray:
    """[res, res, 3] float32 linear HDR image of ``material`` on ``geometry``: its
    ``eval(wi, wo, ShadingPoint(uv, lod, u_level))`` (f*cos, local frame of each hit).

    ``camera`` is a :class:`.geometry.Camera` or :class:`.geometry.OrthographicCamera`, ``lights`` a sequence of
    :class:`.lighting.DirectionalLight` / :class:`.lighting.EnvironmentMap`.
    Each of the ``spp`` passes jitters every pixel's ray, intersects the
    geometry, picks the level of detail from the ray cone (``texels`` = the
    material's finest level, (h, w); the cone's width and spread times ``footprint``, by
    default :func:`sample_footprint_scale` of ``spp``) and the latent level with
    one uniform per pixel, and adds for every directional light ``f*cos(wo) * intensity`` and
    for every environment map one light sample ``f*cos(wo) * L(wo) / pdf(wo)``.
    Light samples do not depend on the material, so two materials rendered
    with the same ``seed`` see the same rays, levels and light directions
    (common random numbers): their difference is the BRDF's, not the noise's.

    ``sampler`` (a material whose ``sample`` and ``pdf`` are used: ``material`` itself, or
    the reference to give several materials the same directions) adds one direction
    sampled from it per environment map and pass, combined with the light sample by
    multiple importance sampling (balance heuristic over the two densities).
    The estimate stays unbiased for ``material`` whatever the sampler is, because the
    environment's density covers every lit direction; a sharp lobe that light
    sampling alone finds only by chance (a clear coat reflecting the sky) then
    converges. The sampler's directions do not depend on ``material`` either, so
    common random numbers hold with it too.
    No shadows; the background (misses) is black. ``wi`` points to the camera.
    """
    g = torch.Generator().manual_seed(seed)
    scale = sample_footprint_scale(spp) if footprint is None else footprint
    centre, radius = geometry.bounds()
    npix = res * res
    img = torch.zeros(npix, 3)
    for _ in range(spp):
        rays = camera.rays(res, centre, radius, g)
        hits = geometry.intersect(rays)
        lod = ray_cone_lod(hits, rays.spread * scale, texels, rays.width * scale)
        u_level = torch.rand(npix, generator=g)
        light_u = [torch.rand(npix, 3, generator=g) if isinstance(li, EnvironmentMap) else None for li in lights]
        bsdf_u = [torch.rand(npix, 2, generator=g) if isinstance(li, EnvironmentMap) and sampler is not None
                  else None for li in lights]
        idx = hits.mask.nonzero()[:, 0]
        if len(idx) == 0:
            continue
        frame = Hits(*(getattr(hits, f.name)[idx] for f in dataclasses.fields(Hits)))
        wi = frame.to_local(-rays.dirs[idx])
        at = ShadingPoint(uv=frame.uv, lod=lod[idx], u_level=u_level[idx])
        acc = torch.zeros(len(idx), 3)
        for li, u, ub in zip(lights, light_u, bsdf_u):
            if isinstance(li, DirectionalLight):
                wo = frame.to_local(li.vector().expand(len(idx), 3))
                weight = li.rgb().expand(len(idx), 3)
            elif isinstance(li, EnvironmentMap):
                d, weight, pdf_light = li.sample(u[idx])
                wo = frame.to_local(d)
                if sampler is not None:
                    # light sample's MIS weight; then the sampler's own direction
                    with torch.no_grad():
                        pdf_bsdf = sampler.pdf(wi, wo, at)
                    weight = weight * _balance(pdf_light, pdf_bsdf)[:, None]
                    acc += _bsdf_sample(material, sampler, li, frame, wi, ub[idx], at)
            else:
                raise TypeError(f"unsupported light {type(li).__name__}")
            with torch.no_grad():
                f = material.eval(wi, wo, at)
            ok = (wo[:, 2:3] > 0) & (wi[:, 2:3] > 0)
            acc += torch.where(ok, f * weight, torch.zeros_like(f))
        img[idx] += acc
    return (img / spp).view(res, res, 3).numpy().astype(np.float32)


def _balance(p: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """Balance-heuristic weight p / (p + q) of the strategy with density ``p``; 0 where both are 0."""
    return torch.where(p > 0, p / (p + q).clamp_min(1e-30), torch.zeros_like(p))


def _bsdf_sample(material: Material, sampler: Material, env, frame, wi, u, at: ShadingPoint) -> torch.Tensor:
    """One ``sampler`` direction's MIS-weighted contribution f*cos * L * w / pdf [N,3] under ``env``."""
    with torch.no_grad():
        wo, _, pdf = sampler.sample(wi, u, at)
        d = frame.to_world(wo)
        w = _balance(pdf, env.pdf(d))
        f = material.eval(wi, wo, at)
    ok = (wo[:, 2:3] > 0) & (wi[:, 2:3] > 0) & (pdf[:, None] > 0)
    contrib = f * env.radiance(d) * (w / pdf.clamp_min(1e-30))[:, None]
    return torch.where(ok & torch.isfinite(contrib), contrib, torch.zeros_like(contrib))


def image_errors(ref: np.ndarray, test: np.ndarray) -> dict:
    """HDR FLIP (mean, and flip-evaluator's colour-mapped error map; :func:`.flip.hdr_flip`, safe for
    black or non-finite images, whose ``flip_note`` says what it did), mean absolute error and
    relative MSE (eps 1e-2)."""
    fmap, mean, note = hdr_flip(ref, test)
    rel = ((test - ref) ** 2 / (ref ** 2 + 1e-2)).mean()
    out = {"flip": float(mean), "flip_map": fmap, "mae": float(np.abs(test - ref).mean()), "relmse": float(rel)}
    if note:
        out["flip_note"] = note
    return out


RESERVED = ("view", "reference", "flip", "flip_map", "flip_note", "mae", "relmse")
"""Keys of compare's per-view dicts that a material's label cannot take."""


def compare(reference: Material, model: Material, texels: tuple[int, int], views=VIEWS, res: int = 96,
            spp: int = 32, geometry=None, lights=None, distance: float = 4.0, mis: bool = True,
            label: str = "neural") -> list[dict]:
    """Per view: the reference's and ``model``'s renders and their errors, ``{"view", "reference": image,
    label: image, "flip", "flip_map", "mae", "relmse"}``; ``label`` names what ``model`` is
    (``"neural"``, ``"analytic"``, ...), so the image is stored under that name.

    ``spp`` sub-pixel samples make both renders converge to the pixel-filtered
    appearance: the reference point-samples full-resolution textures, so with few
    samples it aliases where a pixel covers many texels (a brushed-metal normal
    map at 4 spp adds ~0.05 HDR FLIP of pure aliasing), while the neural model is
    prefiltered by its level of detail, that of one sample's share of the pixel
    (:func:`sample_footprint_scale`): the samples do the pixel's averaging.

    By default the orthographic sphere under each view's directional light
    (:func:`render`). With ``geometry`` and/or ``lights`` (a sequence of lights,
    default each view's directional light) the views are rendered by
    :func:`render_scene` with a perspective :class:`.geometry.Camera` at the
    view's azimuth/elevation and ``distance`` bounding radii (default geometry:
    the sphere). Both renders of a view share its seed and, under environment maps,
    the reference's BSDF samples (``mis``, see :func:`compare_many`).
    """
    return compare_many(reference, {label: model}, texels, views, res, spp, geometry, lights, distance,
                        mis)[label]


def compare_many(reference: Material, models: dict, texels: tuple[int, int], views=VIEWS, res: int = 96,
                 spp: int = 32, geometry=None, lights=None, distance: float = 4.0, mis: bool = True) -> dict:
    """:func:`compare` for several materials (``{label: material}``) against one reference render per
    view: ``{label: [per-view dict with "view", "reference" (the reference's render), label (that
    material's render) and its errors]}``. Labels name the materials (``"neural"``, ``"analytic"``,
    ``"neural 2x16"``...) and cannot be one of :data:`RESERVED`. Under environment maps every render,
    the reference's included, also samples the reference's BSDF (``mis``; :func:`render_scene`'s
    ``sampler``), so the materials see the same directions."""
    clash = [label for label in models if label in RESERVED]
    if clash:
        raise ValueError(f"material labels {clash} clash with compare's keys {RESERVED}")
    out = {label: [] for label in models}
    for i, view in enumerate(views):
        if geometry is None and lights is None:
            def draw(material, view=view, i=i):
                return render(material, view, res, spp, texels, seed=i)
        else:
            scene = (geometry if geometry is not None else Sphere(), Camera(view.azimuth, view.elevation, distance),
                     lights if lights is not None else [DirectionalLight(view.light, view.intensity)])

            def draw(material, scene=scene, i=i, sampler=reference if mis else None):
                return render_scene(material, *scene, res, spp, texels, seed=i, sampler=sampler)
        ref = draw(reference)
        for label, model in models.items():
            test = draw(model)
            out[label].append({"view": view, "reference": ref, label: test, **image_errors(ref, test)})
    return out


def save_png(path, img: np.ndarray, exposure: float = 1.0, linear: bool = True) -> None:
    """Write an 8-bit PNG: a linear HDR image is exposed, clamped and sRGB-encoded;
    ``linear=False`` writes display-ready values as they are (e.g. FLIP's colour-mapped error)."""

    x = img if img.ndim == 3 else np.repeat(img[..., None], 3, -1)
    x = np.clip(x * exposure, 0, 1)
    if linear:
        x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(x.shape[1], x.shape[0], 3, "uint8"))
    out.write_image((x * 255 + 0.5).astype(np.uint8))
    out.close()
