"""Fidelity in the scene: a trained material rendered on the meshes it is bound to.

The stage's own camera and lights view the bound meshes (:mod:`mtlx2neural.render.in_scene`); the HDR
FLIP over the pixels that show them is the record's ``flip_in_scene`` (``preview_flip_in_scene`` for
the UsdPreviewSurface fallback), beside ``in_scene``: how it was viewed and lit, or why there is no figure.
"""

from __future__ import annotations

import math
from pathlib import Path

from mtlx2neural.errors import Mtlx2NeuralError
from mtlx2neural.render.in_scene import compare_in_scene, stage_in_scene
from mtlx2neural.render.renderer import save_png
from mtlx2neural.render.udim_view import ClampToTiles, model_tiles

IN_SCENE_KEYS = {"neural": "flip_in_scene", "analytic": "preview_flip_in_scene"}
"""Record field (:class:`~mtlx2neural.material_record.MaterialRecord`) of each model's in-scene HDR FLIP."""


def measure_in_scene(ref, models: dict, texels: tuple[int, int], src, folder: Path | None = None) -> dict:
    """The record's in-scene fields for ``models`` (labels ``neural`` and/or ``analytic``) on the meshes
    ``src`` is bound to, with its stage's camera and lights (:mod:`mtlx2neural.render.in_scene`):
    ``flip_in_scene`` / ``preview_flip_in_scene`` (HDR FLIP over the pixels that show the meshes) and
    ``in_scene`` (camera, lights, prims, triangles, resolution, samples, the whole-image FLIP, coverage,
    seconds, notes). ``{}`` for a source without a stage file or bound prims (``.mtlx``); when the stage
    gives nothing to render, or reading it fails, ``in_scene`` says why and there is no figure.
    ``folder``: also write ``in_scene_reference.png``, ``in_scene_<label>.png`` and ``in_scene_flip.png``."""
    stage_file = getattr(src, "stage_file", None)
    if not stage_file or not src.bound_prims:
        return {}
    try:
        scene = stage_in_scene(stage_file, src.bound_prims)
        if isinstance(scene, str):
            return {"in_scene": {"measured": False, "why": scene}}
        # a UDIM model reads the meshes' own uv, kept inside its trained tiles (edge points move)
        models = {label: ClampToTiles(m, model_tiles(m)) if model_tiles(m) else m for label, m in models.items()}
        results = compare_in_scene(ref, models, texels, scene)
    except (Mtlx2NeuralError, OSError, ValueError, RuntimeError) as exc:  # a measure never fails the training
        return {"in_scene": {"measured": False, "why": f"{type(exc).__name__}: {exc}"}}
    first = results[next(iter(results))]
    if not math.isfinite(first["flip"]):  # every pixel black in every render: back faces, or no light above
        return {"in_scene": {"measured": False, **scene.record,
                             "why": "the in-scene render shows nothing lit (back faces, or every light below the "
                                    "surfaces' horizon)"}}
    out = {IN_SCENE_KEYS[label]: round(r["flip"], 4) for label, r in results.items()}
    out["in_scene"] = {"measured": True, **scene.record, "res": first["res"], "spp": first["spp"],
                       "coverage": first["coverage"],
                       "flip_image": {label: round(r["flip_image"], 4) for label, r in results.items()},
                       "seconds": {label: r["seconds"] for label, r in results.items()}}
    if folder is not None:
        save_png(folder / "in_scene_reference.png", first["reference"])
        for label, r in results.items():
            save_png(folder / f"in_scene_{label}.png", r[label])
        save_png(folder / "in_scene_flip.png", first["flip_map"], linear=False)
    return out
