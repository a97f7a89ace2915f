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

from mtlx2neural.contract import Material, ShadingPoint, coverage_of, emission_of
from mtlx2neural.render.flip import hdr_flip
from mtlx2neural.render.geometry import (
    Camera,
    Hits,
    OrthographicCamera,
    Sphere,
    ray_cone_lod,
)
from mtlx2neural.render.lighting import DirectionalLight, EnvironmentMap
from mtlx2neural.render.prefiltered import PrefilteredEnvironment, has_environment_head
from mtlx2neural.render.replayed_sampler import ReplayedSampler


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
    A :class:`.prefiltered.PrefilteredEnvironment` in ``lights`` shades every material with an
    environment head from its learned lobes, deterministically (:mod:`.prefiltered`), and the others
    as its environment map.
    The estimate stays unbiased for ``material`` whatever the sampler is, because the
    environment's density covers every lit direction; a sharp lobe that light
    sampling alone finds only by chance (a clear coat reflecting the sky) then
    converges. The sampler's directions do not depend on ``material`` either, so
    common random numbers hold with it too.
    A material that emits (:func:`~mtlx2neural.contract.emission_of`) adds its emitted radiance where
    the surface faces the camera. A material with an opacity (:func:`~mtlx2neural.contract.coverage_of`:
    a cut-out alpha-tested, a blend as a fraction) covers that share of the pixel, and the ray continues
    beyond the hit for the rest (at most :data:`MAX_LAYERS` surfaces), so the background or the geometry
    behind shows through; the same holds for every material, so the reference and a model cover the
    same pixels where their opacities agree.
    A whole scene: ``material`` a list, indexed by the mesh's per-triangle
    :attr:`.geometry.Mesh.material_index` (``sampler`` and ``texels`` then lists of the same length, or one
    for all).
    No shadows; the background (misses) is black. ``wi`` points to the camera.
    """
    materials = list(material) if isinstance(material, (list, tuple)) else [material]
    samplers = list(sampler) if isinstance(sampler, (list, tuple)) else [sampler] * len(materials)
    grids = list(texels) if texels and isinstance(texels[0], (list, tuple)) else [texels] * len(materials)
    g = torch.Generator().manual_seed(seed)
    scale = sample_footprint_scale(spp) if footprint is None else footprint
    centre, radius = geometry.bounds()
    npix = res * res
    img = torch.zeros(npix, 3)
    envs = [isinstance(li, (EnvironmentMap, PrefilteredEnvironment)) for li in lights]
    per_batch = max(1, min(spp, PASS_BATCH_POINTS // npix))
    for first in range(0, spp, per_batch):
        # Trace a batch of passes (their random numbers drawn in pass order), then shade each material's hits
        # of the whole batch at once: the same samples as pass by pass, in fewer and larger tensor operations.
        deferred = [[] for _ in materials]
        for _ in range(first, min(spp, first + per_batch)):
            rays = camera.rays(res, centre, radius, g)
            u_level = torch.rand(npix, generator=g)
            light_u = [torch.rand(npix, 3, generator=g) if env else None for env in envs]
            bsdf_u = [torch.rand(npix, 2, generator=g) if env and sampler is not None else None for env in envs]
            throughput = torch.ones(npix)  # what the surfaces in front left of each pixel (cut-outs, blending)
            for _layer in range(MAX_LAYERS):
                hits = geometry.intersect(rays)
                idx = (hits.mask & (throughput > MIN_THROUGHPUT)).nonzero()[:, 0]
                if len(idx) == 0:
                    break
                alpha_all = torch.ones(len(idx))
                which = hits.material[idx] if hits.material is not None else torch.zeros(len(idx), dtype=torch.long)
                for m in torch.unique(which).tolist():  # one group of hits per material of the scene
                    sub = idx[which == m]
                    frame = _select_hits(hits, sub)
                    lod = ray_cone_lod(frame, rays.spread * scale, grids[m], rays.width * scale)
                    at = ShadingPoint(uv=frame.uv, lod=lod, u_level=u_level[sub])
                    with torch.no_grad():
                        alpha = coverage_of(materials[m], at)
                    alpha = torch.ones(len(sub)) if alpha is None else alpha.float().cpu()
                    deferred[m].append(_Shading(sub, alpha * throughput[sub], frame, -rays.dirs[sub], at,
                                                [u if u is None else u[sub] for u in light_u],
                                                [u if u is None else u[sub] for u in bsdf_u]))
                    alpha_all[which == m] = alpha
                throughput[idx] = throughput[idx] * (1.0 - alpha_all)
                if not bool((throughput[idx] > MIN_THROUGHPUT).any()):
                    break
                # Continue every ray just beyond its hit: the next layer shows what the cut-out lets through.
                tmin = torch.full((npix,), math.inf)
                tmin[idx] = hits.t[idx] * (1.0 + 1e-5) + 1e-5
                rays = dataclasses.replace(rays, tmin=tmin)
        for m, parts in enumerate(deferred):
            if parts:
                batch = _Shading.cat(parts)
                acc = _shade(materials[m], samplers[m], lights, batch.frame, batch.to_camera, batch.at,
                             batch.light_u, batch.bsdf_u)
                img.index_add_(0, batch.pixels, acc.float().cpu() * batch.weight[:, None])
    return (img / spp).view(res, res, 3).numpy().astype(np.float32)


MAX_LAYERS = 8
"""Surfaces a ray passes through at most (each a cut-out's or a blended surface's hit)."""
MIN_THROUGHPUT = 1e-3
"""A ray stops once the surfaces in front leave less than this of its pixel."""
PASS_BATCH_POINTS = 1 << 16
""":func:`render_scene` shades the hits of as many passes at once as fit this many pixels (at least one
pass): a 96^2 summary view shades 7 passes per call. Larger calls amortise each tensor operation's fixed
cost: the summary's views render 1.6x faster than pass by pass on 2 CPU cores."""


def _select_hits(hits: Hits, index: torch.Tensor) -> Hits:
    """The rows ``index`` of every field of ``hits`` (a None field stays None)."""
    return Hits(*(None if getattr(hits, f.name) is None else getattr(hits, f.name)[index]
                  for f in dataclasses.fields(Hits)))


@dataclasses.dataclass
class _Shading:
    """One material's hits of one layer of one pass, waiting to be shaded (:func:`render_scene`):
    ``pixels`` [N] their pixels, ``weight`` [N] the share of each pixel they cover (coverage times what the
    surfaces in front left), and :func:`_shade`'s inputs."""

    pixels: torch.Tensor
    weight: torch.Tensor
    frame: Hits
    to_camera: torch.Tensor
    at: ShadingPoint
    light_u: list
    bsdf_u: list

    @staticmethod
    def cat(parts: list[_Shading]) -> _Shading:
        """The parts' rows end to end."""
        def cat(xs):
            return None if xs[0] is None else torch.cat(xs)
        first = parts[0]
        frame = Hits(*(cat([getattr(p.frame, f.name) for p in parts]) for f in dataclasses.fields(Hits)))
        at = ShadingPoint(**{f.name: cat([getattr(p.at, f.name) for p in parts])
                             for f in dataclasses.fields(ShadingPoint) if f.name != "params"})
        return _Shading(cat([p.pixels for p in parts]), cat([p.weight for p in parts]), frame,
                        cat([p.to_camera for p in parts]), at,
                        [cat([p.light_u[k] for p in parts]) for k in range(len(first.light_u))],
                        [cat([p.bsdf_u[k] for p in parts]) for k in range(len(first.bsdf_u))])


def _shade(material: Material, sampler, lights, frame: Hits, to_camera, at: ShadingPoint,
           light_u, bsdf_u) -> torch.Tensor:
    """[N, 3] radiance towards the camera from the hits ``frame``: the emission (no cosine) plus,
    per light, ``f*cos * intensity`` (directional) or one light sample MIS-weighted against ``sampler``
    and one ``sampler`` direction (environment); a :class:`.prefiltered.PrefilteredEnvironment` shades a
    material with an environment head without sampling (the others as its plain environment map)."""
    wi = frame.to_local(to_camera)
    n = wi.shape[0]
    acc = torch.zeros(n, 3)
    with torch.no_grad():
        emitted = emission_of(material, at)
    if emitted is not None:
        acc += torch.where(wi[:, 2:3] > 0, emitted.to(acc.dtype), torch.zeros_like(acc))
    for li, u, ub in zip(lights, light_u, bsdf_u):
        if isinstance(li, PrefilteredEnvironment):
            if has_environment_head(material):
                acc += li.shade(material, frame, wi, at).to(acc.dtype)
                continue
            li = li.env  # no environment head (a reference): the map's Monte-Carlo estimate
        if isinstance(li, DirectionalLight):
            wo = frame.to_local(li.vector().expand(n, 3))
            weight = li.rgb().expand(n, 3)
        elif isinstance(li, EnvironmentMap):
            d, weight, pdf_light = li.sample(u)
            wo = frame.to_local(d)
            if sampler is not None:
                # light sample's MIS weight; then the sampler's own direction
                with torch.no_grad():
                    pdf_bsdf = sampler.pdf(wi, wo, at)
                weight = weight * _balance(pdf_light, pdf_bsdf)[:, None]
                acc += _bsdf_sample(material, sampler, li, frame, wi, ub, at)
        else:
            raise TypeError(f"unsupported light {type(li).__name__}")
        with torch.no_grad():
            f = material.eval(wi, wo, at)
        ok = (wo[:, 2:3] > 0) & (wi[:, 2:3] > 0)
        acc += torch.where(ok, f * weight, torch.zeros_like(f))
    return acc


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


CAMERA_DISTANCE = 4.0
"""The perspective camera's distance from the sphere's centre in :func:`compare`'s scenes (lights or geometry given)."""
RESERVED = ("view", "reference", "flip", "flip_map", "flip_note", "mae", "relmse")
"""Keys of compare's per-view dicts that a material's label cannot take."""


def compare(reference: Material, model: Material, texels: tuple[int, int], views=VIEWS, res: int = 96,
            spp: int = 32, geometry=None, lights=None, distance: float = CAMERA_DISTANCE, mis: bool = True,
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
                 spp: int = 32, geometry=None, lights=None, distance: float = CAMERA_DISTANCE, mis: bool = True,
                 sampler: Material | None = None) -> dict:
    """:func:`compare` for several materials (``{label: material}``) against one reference render per
    view: ``{label: [per-view dict with "view", "reference" (the reference's render), label (that
    material's render) and its errors]}``. Labels name the materials (``"neural"``, ``"analytic"``,
    ``"neural 2x16"``...) and cannot be one of :data:`RESERVED`. Under environment maps every render,
    the reference's included, also samples the reference's BSDF (``mis``; :func:`render_scene`'s
    ``sampler``), so the materials see the same directions; ``sampler`` replaces the reference as that
    sampler (e.g. a :class:`.mixture_sampler.MixtureSampler` of the reference and the model). The sampler's
    answers for the reference's render are replayed for the others (:class:`.replayed_sampler.ReplayedSampler`)."""
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

            # every render of the view asks the sampler the same questions: answered once, then replayed
            def draw(material, scene=scene, i=i, sampler=ReplayedSampler(sampler or reference) if mis else None):
                if sampler is not None:
                    sampler.start()
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
