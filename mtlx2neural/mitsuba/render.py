"""``mtlx2neural render ASSET --renderer mitsuba``: a converted USD stage rendered by Mitsuba 3's path tracer,
every material bound to its plugin, and the conversion's in-scene measure repeated in Mitsuba.

:func:`render_stage` draws what the report's scene view draws (:mod:`mtlx2neural.report.scene_view`:
:func:`~mtlx2neural.report.scene_view.gather` and :func:`~mtlx2neural.report.scene_view.scene_mesh`): every
material the neural layer records, converted and skipped, on its bound meshes, seen by the stage's first
perspective camera (else the framing camera of the drawn meshes) under the stage's distant and dome
lights (else the procedural sky), translated by :mod:`.scene` (world y up, stage units; images linear
RGB radiance, float32, row 0 at the top). Each material is bound to:

- ``model="neural"``: ``mtlx_neural`` (the layer, the material's prim) for a converted or flagged
  material, with its exported emission and opacity maps; a skipped one (or one whose neural model cannot be
  read) with ``mtlx_reference``;
- ``model="reference"``: ``mtlx_reference`` (the layer's source stage, the prim) with the reference's own
  emission and opacity, sampled on the material's latent grid (:data:`.scene.SURFACE_GRID` for one the
  layer skipped);
- a grey ``diffuse`` (albedo 0.18, the scene view's stand-in) when neither loads (the reference of an
  unsupported node, a plugin error); the summary's ``notes`` say which and why.

Integrator: Mitsuba's ``path`` with ``max_depth`` (at least 3: one cut-out passed through and the surface
behind it lit; see :class:`~mtlx2neural.report.options.RenderOptions`), ``hide_emitters`` off (the
environment and emitters seen directly show, as in a beauty render); sampler ``independent`` seeded with
``seed``; film ``hdrfilm`` res x res with a ``box`` filter (each pixel the mean of its own samples, as the
torch renderer's; :mod:`.scene`). Unlike the torch renderer it traces shadows and interreflections.

:func:`in_scene_flip` repeats a material's record's ``flip_in_scene`` (:mod:`mtlx2neural.pipeline.in_scene_measure`)
with Mitsuba rendering both sides: the material alone on its own bound meshes
(:func:`mtlx2neural.render.in_scene.stage_in_scene`, the setup the record used), ``mtlx_reference`` and
``mtlx_neural`` at the same seed, HDR FLIP over the pixels that show the meshes (as
:func:`mtlx2neural.render.in_scene.compare_in_scene`: where either image is not black; under an environment,
whose background is never black, where the pixel's centre ray hits the meshes).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from mtlx2neural.errors import InputError
from mtlx2neural.mitsuba import load_mitsuba, mitsuba_missing
from mtlx2neural.mitsuba.scene import (
    SURFACE_GRID,
    Binding,
    material_grid,
    pixel_ids,
    render,
    scene_dict,
    surface_terms,
)
from mtlx2neural.pipeline.layout import names_entry
from mtlx2neural.pipeline.output_safety import check_render_outputs
from mtlx2neural.render.flip import hdr_flip
from mtlx2neural.render.in_scene import stage_in_scene
from mtlx2neural.render.lighting import EnvironmentMap
from mtlx2neural.report.options import RenderOptions
from mtlx2neural.report.scene_view import GreyStandIn, SceneEntry, gather, scene_mesh
from mtlx2neural.report.views import (
    conversion_outputs,
    neural_layer_record,
    write_exr,
    write_png,
)
from mtlx2neural.scene.dependencies import canonical, input_files

MIN_DEPTH = 3
"""The shortest ``max_depth`` accepted: emitters, direct light, and a cut-out passed through (module docstring)."""
GREY = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [GreyStandIn.ALBEDO] * 3}}
"""The stand-in of a material that cannot be drawn (the scene view's albedo)."""
IN_SCENE_RES = 96
"""Pixels across the in-scene image (the record's :data:`mtlx2neural.render.in_scene.RES`)."""
IN_SCENE_SPP = 16
"""Samples per pixel of each in-scene render (the record's :data:`mtlx2neural.render.in_scene.SPP`). Both renders
use one seed, so the ``independent`` sampler gives every pixel the same sample sequence in both: the same
sub-pixel positions and light samples, and BSDF samples from the same numbers (common random numbers, as
the torch measure's); on the glow_and_leaves sample the figure moves by about 1e-4 from seed to seed."""
TORCH_ONLY = {"geometry": "sphere", "env": "sky", "mis": "own", "azimuth": 30.0, "elevation": 20.0,
              "distance": 4.0, "fov": 30.0, "tile": None, "frame": None, "fps": None}
"""Options of the torch renderer that Mitsuba's ignores (with a note when set), and their defaults."""


def _mitsuba():
    """The ``mitsuba`` module, or :class:`InputError` saying what to install."""
    reason = mitsuba_missing()
    if reason is not None:
        raise InputError(reason)
    return load_mitsuba()


def neural_layer_of(asset) -> Path:
    """The neural layer to render for ``asset``: the layer itself, or the one ``mtlx2neural ASSET`` wrote
    beside the original stage (:func:`~mtlx2neural.report.views.conversion_outputs`) for that stage;
    :class:`InputError` when there is none."""
    if neural_layer_record(asset) is not None:
        return Path(asset)
    layer = conversion_outputs(asset).layer
    record = neural_layer_record(layer)
    if record is None or record.source != canonical(asset):
        raise InputError(f"{asset}: no neural layer of it ({layer} is missing or was written for another input); "
                         f"convert it first (mtlx2neural {asset}) or pass the *_neural.usda layer")
    return layer


def _matches(entry: SceneEntry, material: str) -> bool:
    """Whether ``material`` names the gathered ``entry`` (:func:`~mtlx2neural.pipeline.layout.names_entry`, or
    its MaterialX material name)."""
    return (names_entry(material, getattr(entry.record, "material", None), entry.prim)
            or material == getattr(entry.record, "mtlx_material", None))


def _load_bsdf(mi, spec: dict, what: str, notes: list[str]):
    """The loaded BSDF of ``spec``, or None with a note when it cannot be loaded."""
    try:
        return mi.load_dict(spec)
    except Exception as exc:  # noqa: BLE001 - a plugin's failure to load is reported, the scene still renders
        notes.append(f"{what}: {spec['type']} cannot be loaded ({type(exc).__name__}: {exc})")
        return None


def bind(mi, entry: SceneEntry, model: str, layer: Path, source: Path, notes: list[str]) -> tuple[Binding, str]:
    """(:class:`~.scene.Binding`, how it is drawn in words) of one gathered material for ``model``
    (module docstring)."""
    own = entry.status in ("converted", "flagged")
    if model == "neural" and own:
        bsdf = _load_bsdf(mi, {"type": "mtlx_neural", "filename": str(layer), "material": entry.prim},
                          entry.prim, notes)
        if bsdf is not None:
            neural = entry.models["neural"]
            return Binding(bsdf, surface_terms(neural, material_grid(neural))), "mtlx_neural"
    reference = entry.models.get("reference")
    if model == "neural" and not own:
        notes.append(f"{entry.prim}: {entry.status} ({entry.reason}): drawn with its reference")
    if reference is not None and not isinstance(reference, GreyStandIn):
        bsdf = _load_bsdf(mi, {"type": "mtlx_reference", "filename": str(source), "material": entry.prim},
                          entry.prim, notes)
        if bsdf is not None:
            grid = entry.texels if own else SURFACE_GRID
            return Binding(bsdf, surface_terms(reference, material_grid(reference, grid))), "mtlx_reference"
    else:
        notes.append(f"{entry.prim}: {entry.drawn}")
    notes.append(f"{entry.prim}: drawn as a grey diffuse (albedo {GreyStandIn.ALBEDO})")
    return Binding(dict(GREY)), "grey diffuse"


def _check_options(options: RenderOptions) -> list[str]:
    """Validate what Mitsuba's render reads of ``options``; notes naming the torch renderer's options set."""
    output = Path(options.output)
    if output.suffix.lower() != ".exr":
        raise InputError(f"{output}: the output must be an .exr file (a .png is written beside it)")
    if not output.parent.is_dir():
        raise InputError(f"{output.parent}: the output folder does not exist")
    if options.model not in ("reference", "neural"):
        raise InputError(f"unknown model '{options.model}': use reference or neural")
    if options.res < 1 or options.spp < 1:
        raise InputError(f"--res and --spp must be positive (got {options.res}, {options.spp})")
    if options.max_depth < MIN_DEPTH:
        raise InputError(f"--max-depth {options.max_depth}: Mitsuba's paths need at least {MIN_DEPTH} interactions "
                         f"(emitters, direct light, and the surface behind a cut-out)")
    if options.checkpoint:
        raise InputError("--checkpoint: the Mitsuba renderer reads the exported neural layer only (mtlx_neural); "
                         "render a checkpoint with --renderer torch")
    return [f"--{k.replace('_', '-')} is the torch renderer's: ignored" for k, default in TORCH_ONLY.items()
            if getattr(options, k) != default]


def render_stage(asset, options: RenderOptions) -> dict:
    """Render the converted stage ``asset`` (its neural layer ``*_neural.usda``, or the original stage with
    that layer beside it) with Mitsuba (module docstring); write ``options.output`` (linear float32 EXR) and an
    sRGB PNG beside it, each through a temporary file renamed into place. ``options.material`` (optional)
    draws that material's meshes only. Returns a summary: ``materials`` (prim -> how it was drawn),
    ``material``, ``model``, ``renderer``, ``res``, ``spp``, ``max_depth``, ``seed``, ``seconds`` (scene build
    and render), ``exr``, ``png``, ``mean`` (the image's mean radiance), ``notes``. Bad input, or no
    Mitsuba here, raises :class:`InputError`."""
    notes = _check_options(options)
    mi = _mitsuba()
    layer = neural_layer_of(asset)
    record = neural_layer_record(layer)
    output, png = Path(options.output), Path(options.output).with_suffix(".png")
    inputs = input_files(asset) | (input_files(record.source) if record and record.source else set())
    check_render_outputs([output, png], inputs, asset)  # never an input, an export or a neural layer
    gathered = gather(layer)
    if isinstance(gathered, str):
        raise InputError(f"{layer}: {gathered}")
    source, entries = gathered
    if options.material is not None:
        entries = [e for e in entries if _matches(e, options.material)]
        if not entries:
            raise InputError(f"{layer}: no material {options.material!r} among the layer's materials")
    t0 = time.time()
    scene = scene_mesh(source, entries, options.res, options.seed)
    if isinstance(scene, str):
        raise InputError(f"{layer}: {scene}")
    notes += scene.record.get("notes", [])
    bindings, drawn = [], {}
    for e in entries:
        binding, how = bind(mi, e, options.model, layer, source, notes)
        bindings.append(binding)
        drawn[e.prim] = how
    loaded = mi.load_dict(scene_dict(mi, scene, bindings, options.res, options.spp, options.max_depth,
                                     hide_emitters=False))
    img = render(mi, loaded, seed=options.seed)
    seconds = time.time() - t0
    write_exr(output, img)
    write_png(png, img)
    return {"material": list(drawn), "materials": drawn, "model": options.model, "renderer": "mitsuba",
            "neural_source": "layer", "neural_path": str(layer), "camera": scene.record.get("camera"),
            "lights": scene.record.get("lights"), "res": options.res, "spp": options.spp,
            "max_depth": options.max_depth, "seed": options.seed, "seconds": round(seconds, 2),
            "exr": str(output), "png": str(png), "mean": float(np.mean(img)), "notes": list(dict.fromkeys(notes))}


def _shown(mi, loaded, scene, ref: np.ndarray, test: np.ndarray, res: int) -> np.ndarray:
    """The pixels that show the meshes (module docstring)."""
    if any(isinstance(li, EnvironmentMap) for li in scene.lights):
        return pixel_ids(mi, loaded, res) >= 0
    return (ref.sum(-1) > 0) | (test.sum(-1) > 0)


def in_scene_flip(layer, material: str | None = None, res: int = IN_SCENE_RES, spp: int = IN_SCENE_SPP,
                  seed: int = 0, max_depth: int = MIN_DEPTH) -> dict:
    """``{prim: {"mitsuba", "record", "coverage", "res", "spp", "max_depth", "seconds", "images"}}`` for every
    converted (or flagged) material of the neural ``layer`` (only ``material``, a prim path, prim name or
    MaterialX name, when given): ``mitsuba`` the HDR FLIP of ``mtlx_neural`` against ``mtlx_reference`` on the
    material's own meshes (module docstring), ``record`` the record's ``flip_in_scene`` (None when it has
    none), ``coverage`` the share of pixels compared, ``images`` ``{"reference", "neural"}`` ([res, res, 3]
    linear RGB). A material with nothing to render, or whose reference image is black everywhere, gets
    ``mitsuba`` NaN and ``why``."""
    mi = _mitsuba()
    if max_depth < MIN_DEPTH:
        raise InputError(f"max_depth {max_depth}: at least {MIN_DEPTH} (module docstring)")
    gathered = gather(Path(layer))
    if isinstance(gathered, str):
        raise InputError(f"{layer}: {gathered}")
    source, entries = gathered
    chosen = [e for e in entries if e.status in ("converted", "flagged")
              and (material is None or _matches(e, material))]
    if material is not None and not chosen:
        raise InputError(f"{layer}: no converted material {material!r}")
    out = {}
    for e in chosen:
        row = {"mitsuba": math.nan, "record": e.record.flip_in_scene, "res": res, "spp": spp, "max_depth": max_depth}
        out[e.prim] = row
        scene = stage_in_scene(source, e.record.bound_prims, res)
        if isinstance(scene, str):
            row["why"] = scene
            continue
        t0 = time.time()
        neural = e.models["neural"]
        sides = {"reference": Binding({"type": "mtlx_reference", "filename": str(source), "material": e.prim},
                                      surface_terms(e.models["reference"], e.texels)),
                 "neural": Binding({"type": "mtlx_neural", "filename": str(Path(layer)), "material": e.prim},
                                   surface_terms(neural, material_grid(neural)))}
        images, loaded = {}, None
        for label, binding in sides.items():
            loaded = mi.load_dict(scene_dict(mi, scene, [binding], res, spp, max_depth, hide_emitters=False))
            images[label] = render(mi, loaded, seed=seed)
        ref, test = images["reference"], images["neural"]
        shown = _shown(mi, loaded, scene, ref, test, res)
        row.update(images=images, coverage=round(float(shown.mean()), 4), seconds=round(time.time() - t0, 2))
        if float(ref.max()) <= 0 or not shown.any():
            row["why"] = "the reference render shows nothing lit"
            continue
        raw = hdr_flip(ref, test, apply_magma=False)[0][..., 0]
        row["mitsuba"] = round(float(raw[shown].mean()), 4)
    return out
