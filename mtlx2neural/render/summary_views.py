"""The views behind a material's summary figure (``flip_mean``, ``flip_per_view``): what a viewer shows.

Four renders of the unit sphere, each compared with the reference's render of the same view (HDR FLIP):

1. Three directional views (:data:`~mtlx2neural.render.renderer.VIEWS`): an orthographic camera and one
   directional light each. In the first, the mirror direction of the light lies on the visible surface
   (the half vector of light and camera faces the camera), so a sharp highlight the model loses shows.
2. One environment view (:data:`ENVIRONMENT_VIEW`): a perspective camera under the procedural sky
   (:meth:`~mtlx2neural.render.lighting.EnvironmentMap.sky`), every render estimated with one light
   sample and one BSDF sample per pass (multiple importance sampling), drawn from the reference's and the
   model's samplers mixed (:class:`~.mixture_sampler.MixtureSampler`; the reference's alone for a UDIM
   material's tiles). A coat's reflection of the sky so converges in the reference, and a model's own
   sharp lobe converges too: a lost reflection shows, not the estimator's noise.

The mean over the four is the figure: a lost highlight and a lost reflection both raise it.
:func:`describe` says how it was made, in the material's record (``flip_views``).

The environment view above measures the model's BRDF, as a path tracer shades it. A viewer shades an
environment differently: the MaterialX node and the Slang module's ``shadeEnvironment`` read the model's
prefiltered environment path (:mod:`.prefiltered`, the node's default with an environment head), whose
split-sum factorisation has its own error. :func:`viewer_view` measures that path on the same view against
a reference render of more passes: the record's ``flip_viewer``, beside the figure, not in its mean (the
mean stays the BRDF's measure, comparable with older records).
"""

from __future__ import annotations

from mtlx2neural.render.geometry import Camera, Sphere
from mtlx2neural.render.lighting import EnvironmentMap
from mtlx2neural.render.mixture_sampler import MixtureSampler
from mtlx2neural.render.prefiltered import PrefilteredEnvironment, has_environment_head
from mtlx2neural.render.renderer import (
    CAMERA_DISTANCE,
    VIEWS,
    View,
    compare_many,
    image_errors,
    render_scene,
    sample_footprint_scale,
)
from mtlx2neural.render.udim_view import compare_tiles

ENVIRONMENT_VIEW = View(30.0, 20.0)
"""Camera of the environment view (azimuth, elevation in degrees): the sky's sun (azimuth 30, elevation
45) reflects on the sphere's upper half."""
DIRECTIONAL_SPP = 32
"""Jittered passes of each directional view (the pixel's filter: :func:`~.renderer.compare`)."""
ENVIRONMENT_SPP = 32
"""Passes of the environment view (each a light sample and a BSDF sample, MIS-combined)."""
RES = 96
"""Pixels along each side of every view."""
VIEWER_SPP = 16
"""Jittered passes of the viewer view's prefiltered render (:func:`viewer_view`): it draws no random
directions, so the passes only filter the pixel."""
VIEWER_REFERENCE_SPP = 128
"""Passes of the viewer view's reference render. A Lambertian shaded exactly reads HDR FLIP 0.11 against
8 passes, 0.059 against 32 and 0.042 against 128 (48² px): the reference's noise, which the environment
view's common random numbers cancel, counts in full against a noise-free image."""


def _environment_light() -> EnvironmentMap:
    return EnvironmentMap.sky()


def summary_views(reference, models: dict, texels: tuple[int, int], tiles=None, res: int = RES,
                  spp: int | None = None) -> dict:
    """``{label: [per-view dict]}`` (:func:`~mtlx2neural.render.renderer.compare_many`'s rows, each also
    holding ``"lighting"``: ``directional`` or ``environment``): the three directional views, then the
    environment view, for every model of ``models`` against ``reference``. ``tiles`` (UDIM numbers):
    the views once per tile, tile by tile (:func:`~mtlx2neural.render.udim_view.compare_tiles`). ``res``,
    ``spp``: every view's size and passes (None: :data:`DIRECTIONAL_SPP` and :data:`ENVIRONMENT_SPP`;
    smaller ones for tests of what is recorded, not of the figure)."""

    def views(**kw):
        return compare_tiles(reference, models, texels, tiles, **kw) if tiles else \
            compare_many(reference, models, texels, **kw)

    lit = views(views=VIEWS, res=res, spp=spp or DIRECTIONAL_SPP)
    sky = dict(views=(ENVIRONMENT_VIEW,), res=res, spp=spp or ENVIRONMENT_SPP, lights=[_environment_light()])
    if tiles:  # the tiles' views wrap every material per tile: the reference's sampler alone
        env = views(**sky)
    else:  # per model, the reference's and the model's samplers mixed (the same directions for both renders)
        env = {label: compare_many(reference, {label: model}, texels, sampler=MixtureSampler(reference, model),
                                   **sky)[label] for label, model in models.items()}
    out = {}
    for label in models:
        rows = [{**r, "lighting": "directional"} for r in lit[label]]
        env_rows = [{**r, "lighting": "environment"} for r in env[label]]
        if tiles:  # tile by tile: each tile's directional views, then its environment view
            per = len(VIEWS)
            rows = [r for k in range(len(tiles)) for r in (*rows[k * per:(k + 1) * per], env_rows[k])]
        else:
            rows += env_rows
        out[label] = rows
    return out


def viewer_view(reference, model, texels: tuple[int, int], res: int = RES, spp: int = VIEWER_SPP,
                reference_spp: int = VIEWER_REFERENCE_SPP, seed: int = 0) -> dict | None:
    """The environment view shaded as a viewer shades it: ``model`` under the sky by its prefiltered
    environment path (:class:`~.prefiltered.PrefilteredEnvironment`, ``spp`` jittered passes), against
    ``reference`` in the same view at ``reference_spp`` passes (light and BSDF samples by MIS, the
    reference's sampler: the prefiltered image has no noise, so the reference's own counts in full).
    Returns ``{"image", "reference", "flip", "relmse", "flip_map", ...}`` (:func:`~.renderer.image_errors`),
    or None when ``model`` has no environment head (a viewer then samples its BRDF, as the environment
    view does). Both read the latents at the level of detail of ``reference_spp`` passes."""
    if not has_environment_head(model):
        return None
    v = ENVIRONMENT_VIEW
    camera, sky = Camera(v.azimuth, v.elevation, CAMERA_DISTANCE), _environment_light()
    footprint = sample_footprint_scale(reference_spp)
    target = render_scene(reference, Sphere(), camera, [sky], res, reference_spp, texels, seed=seed,
                          sampler=reference, footprint=footprint)
    image = render_scene(model, Sphere(), camera, [PrefilteredEnvironment(sky)], res, spp, texels, seed=seed,
                         footprint=footprint)
    return {"image": image, "reference": target, **image_errors(target, image)}


def describe_viewer() -> str:
    """How :func:`viewer_view` was made (the record's ``flip_viewer_view``)."""
    v = ENVIRONMENT_VIEW
    return (f"viewer: the environment view (azimuth {v.azimuth:g}, elevation {v.elevation:g}, procedural sky, "
            f"{RES}^2 px) shaded by the prefiltered environment path (the MaterialX node's default: a sharp lobe "
            f"and the learned sampler's two over the sky's filtered levels), {VIEWER_SPP} spp, against the reference at "
            f"{VIEWER_REFERENCE_SPP} spp (light and BSDF samples, MIS)")


def views_per_tile() -> int:
    """Rows :func:`summary_views` gives per tile (or for a material without tiles)."""
    return len(VIEWS) + 1


def describe() -> list[str]:
    """One line per view of :func:`summary_views`, in its order: how the figure was made."""
    lines = [f"directional: orthographic sphere, azimuth {v.azimuth:g}, elevation {v.elevation:g}, light "
             f"towards {tuple(v.light)} x {v.intensity:g}, {RES}^2 px, {DIRECTIONAL_SPP} spp" for v in VIEWS]
    v = ENVIRONMENT_VIEW
    lines.append(f"environment: perspective sphere, azimuth {v.azimuth:g}, elevation {v.elevation:g}, procedural "
                 f"sky, {RES}^2 px, {ENVIRONMENT_SPP} spp, light and BSDF samples (MIS; reference's and model's samplers)")
    return lines
