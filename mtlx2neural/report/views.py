"""``mtlx2neural render``: render one material (reference or trained neural model) to an EXR and a PNG.

The library function :func:`render_asset` does the work; the CLI only parses
arguments. Geometry is ``sphere``, ``plane``, ``teapot`` (MaterialX's
``resources/Geometry/teapot.obj``, found through MATERIALX_SEARCH_PATH or the
``../shared`` assets next to the repository) or a path to an ``.obj``; lighting
is ``sky`` (the procedural :meth:`EnvironmentMap.sky`) or a lat-long ``.hdr``/``.exr``
file. The neural model's checkpoint defaults to the one ``mtlx2neural ASSET``
writes: ``<asset folder>/<asset stem>_neural/<material folder>/checkpoint.pt``.
The EXR (float32 linear RGB) and the PNG (sRGB, exposure 1) are written through
temporary files and renamed into place, so a failed run leaves no partial file.
"""

from __future__ import annotations

import os
import re
import time
from pathlib import Path

import numpy as np

from mtlx2neural.atomic import atomic_path
from mtlx2neural.errors import InputError
from mtlx2neural.graph import compile_material
from mtlx2neural.model.checkpoint import load_checkpoint
from mtlx2neural.pipeline.layout import default_output, material_folder
from mtlx2neural.reference import ReferenceMaterial
from mtlx2neural.render.geometry import Camera, Plane, Sphere, load_obj
from mtlx2neural.render.lighting import EnvironmentMap
from mtlx2neural.render.renderer import render_scene, save_png
from mtlx2neural.report.options import RenderOptions
from mtlx2neural.scene import find_material

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
    import OpenImageIO as oiio

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


def default_checkpoint(asset, material_name: str) -> Path:
    """Where ``mtlx2neural ASSET`` puts the checkpoint of ``material_name`` (or, when only that
    exists, where mtlx2neural 0.2 put it: the name with every run of other characters as ``_``)."""
    out = default_output(asset)
    current = out / material_folder(material_name) / "checkpoint.pt"
    legacy = out / (re.sub(r"[^A-Za-z0-9_.-]+", "_", material_name.strip("/")) or "material") / "checkpoint.pt"
    return legacy if legacy.is_file() and not current.is_file() else current


def render_asset(asset, output: str | Path | RenderOptions, material: str | None = None, model: str = "reference",
                 checkpoint=None,
                 geometry: str = "sphere", env: str | None = "sky", res: int = 256, spp: int = 16,
                 azimuth: float = 30.0, elevation: float = 20.0, distance: float = 4.0, fov: float = 30.0,
                 seed: int = 0, allow_missing_textures: bool = False, mis: str = "own") -> dict:
    """Render ``material`` of ``asset`` with the reference or neural ``model``; write ``output`` (.exr)
    and a PNG beside it. Returns a summary (paths, settings, seconds). Bad input raises InputError.

    ``mis="own"`` adds, per pass, one direction from the model's own sampler (the reference's lobe
    mixture, or the neural model's learned proxy) to the environment's light sample, combined by
    the balance heuristic: a sharp coat reflecting the sky converges instead of sparkling. The
    two models then draw different BSDF directions, so their renders share only the light
    samples; ``mis="none"`` (light samples only) keeps every random number common to both.

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
    if res < 1 or spp < 1:
        raise InputError(f"--res and --spp must be positive (got {res}, {spp})")
    if distance <= 1.0 or not 0.0 < fov < 180.0:
        raise InputError("--distance must exceed 1 (bounding radii) and --fov lie in (0, 180) degrees")
    src = find_material(asset, material)  # InputError for an unknown or ambiguous material
    geo, lights = make_geometry(geometry), make_lights(env)
    if model == "neural":

        ck = Path(checkpoint) if checkpoint else default_checkpoint(asset, src.name)
        material = load_checkpoint(ck)
        texels = tuple(int(s) for s in material.latents.levels[0].shape[1:])
    else:

        compiled = compile_material(src.document, src.material, allow_missing_textures=allow_missing_textures)
        material, texels, ck = ReferenceMaterial(compiled), (1, 1), None
    t0 = time.time()
    # mis="own": the material samples its own directions (the reference's lobe mixture, the neural
    # model's learned proxy), through the Material protocol's sample/pdf.
    img = render_scene(material, geo, Camera(azimuth, elevation, distance, fov), lights, res, spp, texels, seed,
                       sampler=material if mis == "own" else None)
    seconds = time.time() - t0
    png = output.with_suffix(".png")
    write_exr(output, img)
    write_png(png, img)
    return {"material": src.name, "model": model, "checkpoint": str(ck) if ck else None, "exr": str(output),
            "png": str(png), "geometry": geometry, "env": env or "sky", "mis": mis, "res": res, "spp": spp,
            "seconds": round(seconds, 2), "mean": float(np.mean(img))}
