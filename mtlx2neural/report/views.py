"""``mtlx2neural render``: render one material (reference or trained neural model) to an EXR and a PNG.

The library function :func:`render_asset` does the work; the CLI only parses
arguments. Geometry is ``sphere``, ``plane``, ``teapot`` (MaterialX's
``resources/Geometry/teapot.obj``, found through MATERIALX_SEARCH_PATH or the
``../shared`` assets next to the repository) or a path to an ``.obj``; lighting
is ``sky`` (the procedural :meth:`EnvironmentMap.sky`) or a lat-long ``.hdr``/``.exr``
file. The neural model comes from the exported layer and its files (what ships,
:func:`~mtlx2neural.export.load.load_neural`) when there is one, else from the
training checkpoint that ``mtlx2neural ASSET`` writes:
``<asset folder>/<asset stem>_neural/<material folder>/checkpoint.pt``
(:func:`neural_source` says which, and why).
The EXR (float32 linear RGB) and the PNG (sRGB, exposure 1) are written through
temporary files and renamed into place, so a failed run leaves no partial file.
"""

from __future__ import annotations

import math
import os
import re
import time
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
from pxr import Sdf

from mtlx2neural.atomic import atomic_path
from mtlx2neural.errors import InputError
from mtlx2neural.export.load import load_neural
from mtlx2neural.export.usd_writer import LEGACY_DOC_PREFIX, RECORD_KEY, register_schema
from mtlx2neural.graph import compile_material
from mtlx2neural.graph.geometry import bind_geometry
from mtlx2neural.graph.ops import Application
from mtlx2neural.material_record import read_record, record_path
from mtlx2neural.model.checkpoint import load_checkpoint
from mtlx2neural.pipeline.layout import (
    FOLDER_MARKER,
    LAYER_SUFFIXES,
    SNAPSHOT_NAME,
    LayerRecord,
    OutputLayout,
    material_folder,
    names_entry,
    read_layer_record,
    resolve_output,
)
from mtlx2neural.pipeline.output_safety import check_render_outputs
from mtlx2neural.reference import ReferenceMaterial
from mtlx2neural.reference.loading import application_of
from mtlx2neural.reference.measured import load_measured
from mtlx2neural.render.geometry import Camera, Plane, Sphere, load_obj
from mtlx2neural.render.lighting import EnvironmentMap
from mtlx2neural.render.prefiltered import PrefilteredEnvironment
from mtlx2neural.render.renderer import render_scene, save_png
from mtlx2neural.render.udim_view import TileView, model_tiles
from mtlx2neural.report.options import RenderOptions
from mtlx2neural.scene import find_material
from mtlx2neural.scene.dependencies import canonical, input_files

GEOMETRIES = ("sphere", "plane", "teapot")
TEAPOT = Path("resources") / "Geometry" / "teapot.obj"


def find_teapot() -> Path:
    """MaterialX's teapot.obj: under each MATERIALX_SEARCH_PATH entry, then ../shared/assets/materialx."""
    roots = [Path(p) for p in os.environ.get("MATERIALX_SEARCH_PATH", "").split(os.pathsep) if p]
    roots.append(Path(__file__).resolve().parents[3] / "shared" / "assets" / "materialx")
    for root in roots:
        for cand in (root / TEAPOT, root / "Geometry" / "teapot.obj", root / "teapot.obj"):
            if cand.is_file():
                return cand
    raise InputError("teapot.obj not found (looked under MATERIALX_SEARCH_PATH and ../shared/assets/materialx/"
                     f"{TEAPOT}); set MATERIALX_SEARCH_PATH to a MaterialX checkout or pass --geometry FILE.obj")


def make_geometry(spec: str):
    """``sphere`` | ``plane`` | ``teapot`` | a path to an OBJ file -> a geometry of :mod:`.geometry`."""

    if spec == "sphere":
        return Sphere()
    if spec == "plane":
        return Plane()
    if spec == "teapot":
        return load_obj(find_teapot())
    if not spec.lower().endswith(".obj"):
        raise InputError(f"unknown geometry '{spec}': use {', '.join(GEOMETRIES)} or a path to an .obj file")
    return load_obj(spec)


def make_lights(spec: str | None):
    """``sky`` (default) or a lat-long HDR/EXR file -> a list of lights."""

    if spec in (None, "sky"):
        return [EnvironmentMap.sky()]
    return [EnvironmentMap.from_file(spec)]


def write_exr(path, img: np.ndarray) -> None:
    """Write a float32 [H, W, 3] image with OpenImageIO: a temporary file, then os.replace."""

    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), oiio.ImageSpec(img.shape[1], img.shape[0], 3, "float")):
            raise InputError(f"{path}: cannot write the image ({oiio.geterror()})")
        try:
            ok = out.write_image(np.ascontiguousarray(img, dtype=np.float32))
        finally:
            out.close()
        if not ok:
            raise InputError(f"{path}: cannot write the image ({oiio.geterror()})")


def write_png(path, img: np.ndarray) -> None:
    """:func:`.render.save_png` through a temporary file and os.replace."""

    with atomic_path(path) as tmp:
        save_png(tmp, img)


def conversion_outputs(asset) -> OutputLayout:
    """Where ``mtlx2neural ASSET`` (no ``-o``) writes for ``asset``: the folder ``<asset stem>_neural``
    beside it and the layer ``<asset stem>_neural.usda``. A stage snapshot (``OUT/stage-snapshot.usda``
    in a folder this tool marked, written when an in-memory or edited stage was converted) belongs
    to the conversion that wrote it: folder ``OUT``, layer ``OUT.usda``."""
    path = Path(asset).resolve()
    if path.name == SNAPSHOT_NAME and (path.parent / FOLDER_MARKER).is_file():
        return resolve_output(path, path.parent)
    return resolve_output(path)


def default_checkpoint(asset, material_name: str) -> Path:
    """Where ``mtlx2neural ASSET`` puts the checkpoint of ``material_name`` (in the folder of
    :func:`conversion_outputs`; or, when only that exists, where mtlx2neural 0.2 put it: the name
    with every run of other characters as ``_``)."""
    out = conversion_outputs(asset).folder
    current = out / material_folder(material_name) / "checkpoint.pt"
    legacy = out / (re.sub(r"[^A-Za-z0-9_.-]+", "_", material_name.strip("/")) or "material") / "checkpoint.pt"
    return legacy if legacy.is_file() and not current.is_file() else current


def neural_layer_record(asset) -> LayerRecord | None:
    """The record of ``asset`` when it is a neural layer this tool wrote, else None."""
    path = Path(asset)
    if path.suffix.lower() not in LAYER_SUFFIXES or not path.is_file():
        return None
    try:  # the header alone first: an input asset (maybe large) is not read twice
        head = Sdf.Layer.OpenAsAnonymous(str(path), True)  # metadataOnly
    except Exception:  # noqa: BLE001 - any unreadable file is "not a neural layer" here
        return None
    if head is None or (RECORD_KEY not in dict(head.customLayerData)
                        and not (head.documentation or "").startswith(LEGACY_DOC_PREFIX)):
        return None
    return read_layer_record(path)


def _layer_entry(layer: Path, record: LayerRecord, material: str | None) -> tuple[str | None, str | None]:
    """(material name, prim path) of ``material`` among the neural layer's recorded materials;
    (None, material) when the record lists none (a layer of mtlx2neural 0.2: load_neural chooses)."""
    entries = record.materials
    if not entries:
        return None, material
    if material is None:
        if len(entries) == 1:
            name = next(iter(entries))
            return name, entries[name].get("prim")
        raise InputError(f"{layer}: {len(entries)} neural materials ({', '.join(sorted(entries))}); "
                         f"choose one with --material")
    for name, e in entries.items():
        if names_entry(material, name, e.get("prim")):
            return name, e.get("prim") or ""
    raise InputError(f"{layer}: no neural material {material!r}; it holds {', '.join(sorted(entries))}")


def neural_source(asset, material_name: str) -> tuple[str, Path, str | None]:
    """Where the neural model of ``material_name`` of the original ``asset`` comes from, without
    ``--checkpoint``: ``("layer", layer, prim path)`` when the layer of :func:`conversion_outputs`
    exists, was written for this ``asset`` and records this material (it and its files are what
    ships, so they are preferred: a corrupt or missing exported file is then an error, not a
    silent fall-back); else ``("checkpoint", default_checkpoint(...), None)``, as before layers
    were read back."""
    layer = conversion_outputs(asset).layer
    record = neural_layer_record(layer)
    if record is not None and record.source == canonical(asset) and material_name in record.materials:
        return "layer", layer, record.materials[material_name].get("prim")
    return "checkpoint", default_checkpoint(asset, material_name), None


def conversion_application(asset, material_name: str) -> Application | None:
    """The instant ``mtlx2neural ASSET`` baked ``material_name``'s ``time``/``frame`` nodes at (its record
    in the folder of :func:`conversion_outputs`), or None (no conversion, or the graph reads neither). A
    record this version cannot read raises :class:`~mtlx2neural.material_record.RecordError` naming it."""
    folder = conversion_outputs(asset).folder / material_folder(material_name)
    if not record_path(folder).is_file():
        return None
    return application_of(read_record(folder).application)  # a bad or old record: RecordError, named


def render_asset(asset, output: str | Path | RenderOptions, material: str | None = None, model: str = "reference",
                 checkpoint=None,
                 geometry: str = "sphere", env: str | None = "sky", res: int = 256, spp: int = 16,
                 azimuth: float = 30.0, elevation: float = 20.0, distance: float = 4.0, fov: float = 30.0,
                 seed: int = 0, env_mode: str = "sampled", allow_missing_textures: bool = False, mis: str = "own",
                 frame: float | None = None, fps: float | None = None, tile: int | None = None) -> dict:
    """Render ``material`` of ``asset`` with the reference or neural ``model``; write ``output`` (.exr)
    and a PNG beside it. Returns a summary (paths, settings, seconds). Bad input raises InputError.

    ``asset`` is the original asset, a stage snapshot a conversion wrote, or the neural layer
    ``mtlx2neural ASSET`` wrote (recognised by its ``customLayerData`` record). Which neural
    model renders (the summary's ``neural_source``, ``"layer"`` or ``"checkpoint"``, and
    ``neural_path``):

    - ``checkpoint`` given: that training checkpoint (or its folder), always;
    - ``asset`` is a neural layer: the layer and its exported files (:func:`load_neural`:
      FP16 weights, latent EXRs), never a checkpoint; ``model="reference"`` renders the
      original material of the input the layer records;
    - otherwise :func:`neural_source`: the exported layer beside the asset when it records
      this material, else the checkpoint.

    A missing or malformed exported file (latent EXR, weights.bin, weights.json) is an
    :class:`InputError` naming the file.

    ``mis="own"`` adds, per pass, one direction from the model's own sampler (the reference's lobe
    mixture, or the neural model's learned proxy) to the environment's light sample, combined by
    the balance heuristic: a sharp coat reflecting the sky converges instead of sparkling. The
    two models then draw different BSDF directions, so their renders share only the light
    samples; ``mis="none"`` (light samples only) keeps every random number common to both.

    ``env_mode="prefiltered"``: a neural model with an environment head shades the environment from its
    learned lobes (:class:`~mtlx2neural.render.prefiltered.PrefilteredEnvironment`, no noise); the
    reference and models without the head stay sampled (``"sampled"``, the default).

    ``frame``/``fps`` (the reference only): the instant its ``time``/``frame`` nodes fold to; each
    left None is the conversion's (:func:`conversion_application`), else frame 1 at 24 fps.

    ``tile`` (a UDIM number): render the geometry's uv wrapped into that UDIM tile
    (:class:`~mtlx2neural.render.udim_view.TileView`, both models); a UDIM neural model without it
    shows its first trained tile (its other tiles' latents are never read by a [0,1]^2 geometry),
    a tile it was not trained on is an :class:`InputError`. The summary's ``tile`` says which.

    ``render_asset(asset, options)`` takes a :class:`~mtlx2neural.report.options.RenderOptions`
    (``output`` and every argument after it) instead."""
    if isinstance(output, RenderOptions):
        return render_asset(asset, **output.kwargs())

    output = Path(output)
    if output.suffix.lower() != ".exr":
        raise InputError(f"{output}: the output must be an .exr file (a .png is written beside it)")
    if not output.parent.is_dir():
        raise InputError(f"{output.parent}: the output folder does not exist")
    if model not in ("reference", "neural"):
        raise InputError(f"unknown model '{model}': use reference or neural")
    if mis not in ("own", "none"):
        raise InputError(f"unknown --mis '{mis}': use own (the model's sampler) or none (light samples only)")
    if env_mode not in ("sampled", "prefiltered"):
        raise InputError(f"unknown --env-mode '{env_mode}': use sampled or prefiltered")
    if res < 1 or spp < 1:
        raise InputError(f"--res and --spp must be positive (got {res}, {spp})")
    if distance <= 1.0 or not 0.0 < fov < 180.0:
        raise InputError("--distance must exceed 1 (bounding radii) and --fov lie in (0, 180) degrees")
    register_schema()  # before USD's schema registry is first built (a neural layer applies the API)
    record = neural_layer_record(asset)
    src = None
    inputs = input_files(asset)
    if record is not None:  # the neural layer: its record names the materials
        if record.source is not None:
            inputs |= input_files(record.source)
        name, prim = _layer_entry(Path(asset), record, material)
        if model == "reference" and record.source is not None:
            asset, material = record.source, name or material  # the input the layer was written for
        name = name or material
    else:
        src = find_material(asset, material)  # InputError for an unknown or ambiguous material
        name, prim = src.name, None
        inputs |= input_files(asset, [src])
    png = output.with_suffix(".png")
    check_render_outputs([output, png], inputs, asset)  # never an input, an export or a neural layer
    geo, lights = make_geometry(geometry), make_lights(env)
    if env_mode == "prefiltered":
        lights = [PrefilteredEnvironment(li) if isinstance(li, EnvironmentMap) else li for li in lights]
    source, ck = None, None
    if model == "neural":
        if checkpoint:
            source, ck = "checkpoint", Path(checkpoint)
        elif record is not None:
            source, ck = "layer", Path(asset)
        else:
            source, ck, prim = neural_source(asset, name)
        if source == "layer":
            shading = load_neural(ck, prim)
            name = name or shading.usd_info["material"]
        else:
            shading = load_checkpoint(ck)
        texels = tuple(int(s) for s in shading.latents.levels[0].shape[-2:])  # per tile for UDIM
        trained = model_tiles(shading)
        if trained:
            tile = trained[0] if tile is None else int(tile)
            if tile not in trained:
                raise InputError(f"--tile {tile}: {name} was trained on UDIM tiles {trained} only")
        elif tile is not None:
            raise InputError(f"--tile {tile}: {name}'s neural model has no UDIM tiles")
    else:
        src = src or find_material(asset, material)
        app = conversion_application(asset, src.name) or Application()
        app = Application(frame=app.frame if frame is None else float(frame), fps=app.fps if fps is None else float(fps))
        if not (math.isfinite(app.frame) and math.isfinite(app.fps) and app.fps > 0):
            raise InputError(f"--frame {app.frame!r} / --fps {app.fps!r}: must be finite, --fps positive")
        if src.measured:  # a MERL table
            shading, texels, name = load_measured(src.source_file), (1, 1), src.name
        else:
            compiled = compile_material(src.document, src.material, allow_missing_textures=allow_missing_textures,
                                        application=app)
            bind_geometry(compiled, src.stage_file, src.bound_prims)  # as the conversion bakes it
            shading, texels, name = ReferenceMaterial(compiled), (1, 1), src.name
    if tile is not None:
        if int(tile) < 1001:
            raise InputError(f"--tile {tile}: UDIM tiles are numbered from 1001")
        shading = TileView(shading, int(tile))
    t0 = time.time()
    # mis="own": the material samples its own directions (the reference's lobe mixture, the neural
    # model's learned proxy), through the Material protocol's sample/pdf.
    img = render_scene(shading, geo, Camera(azimuth, elevation, distance, fov), lights, res, spp, texels, seed,
                       sampler=shading if mis == "own" else None)
    seconds = time.time() - t0
    write_exr(output, img)
    write_png(png, img)
    return {"material": name, "model": model, "checkpoint": str(ck) if source == "checkpoint" else None,
            "neural_source": source, "neural_path": str(ck) if ck else None, "exr": str(output),
            "png": str(png), "geometry": geometry, "env": env or "sky", "env_mode": env_mode, "mis": mis, "res": res, "spp": spp,
            "seconds": round(seconds, 2), "mean": float(np.mean(img)), "tile": tile}
