"""Emission and opacity maps as files beside the latents, and back.

:func:`write_surface_files` writes a material's :class:`~mtlx2neural.textures.surface_maps.SurfaceMaps`
into its export folder:

- ``emission.exr``: RGB half-float, emitted radiance in linear working-space RGB (colour space
  ``lin_rec709``, the default working space), one MIP level per level of the maps (coverage-weighted
  means, so they are not what a viewer would compute from level 0), periodic wrap;
- ``opacity.exr``: one channel, half-float, the opacity map with its MIP chain (a cut-out's levels are
  coverage-preserving: alpha-test each at ``alpha_cutoff``; a blend's are box means), colour space ``raw``.

A constant needs no file; ``surface.json`` (written beside them, read by the shader generators and
:func:`read_surface_files`; also stored in ``export.json``) holds it: ``{"emission": {"file"} | {"constant": [r, g, b]} | None, "opacity": {"file"} | {"constant": a} |
None, "alpha_mode": "opaque" | "mask" | "blend", "alpha_cutoff": 0.5 | None, "coverage": ...}``.
:func:`read_surface_files` rebuilds the maps from the files (their half values exactly).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from mtlx2neural.atomic import atomic_path
from mtlx2neural.export.latents import write_mip_chain
from mtlx2neural.formats.fp16 import to_fp16
from mtlx2neural.imaging.mip_chain import read_mip_chain
from mtlx2neural.textures.surface_maps import (  # noqa: F401  (MANIFEST_FILE, read_surface_manifest: re-exported)
    MANIFEST_FILE,
    SurfaceMaps,
    read_surface_manifest,
)

EMISSION_FILE = "emission.exr"
OPACITY_FILE = "opacity.exr"


def _write(levels: list[torch.Tensor], path: Path, what: str, colorspace: str) -> list[str]:
    images, notes = [], []
    for j, lv in enumerate(levels):
        half, n = to_fp16(lv.detach().float().cpu().permute(1, 2, 0), f"{what} MIP level {j}")
        images.append(half)
        notes += n
    write_mip_chain(path, images, "periodic", colorspace)
    return notes


def write_surface_files(maps: SurfaceMaps | None, folder) -> tuple[dict | None, list[str]]:
    """Write ``maps`` into ``folder`` (module docstring); returns (the manifest section, or None when the
    material emits nothing and is opaque; FP16 notes)."""
    if maps is None or maps.empty:
        return None, []
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    notes: list[str] = []
    emission = opacity = None
    if maps.emission_levels is not None:
        notes += _write(maps.emission_levels, folder / EMISSION_FILE, "emission", "lin_rec709")
        emission = {"file": EMISSION_FILE, "levels": len(maps.emission_levels)}
    elif maps.emission_constant is not None:
        emission = {"constant": [float(x) for x in maps.emission_constant]}
    if maps.opacity_levels is not None:
        notes += _write(maps.opacity_levels, folder / OPACITY_FILE, "opacity", "raw")
        opacity = {"file": OPACITY_FILE, "levels": len(maps.opacity_levels)}
    elif maps.opacity_constant is not None:
        opacity = {"constant": float(maps.opacity_constant)}
    manifest = {"emission": emission, "opacity": opacity, "alpha_mode": maps.alpha_mode,
                "alpha_cutoff": maps.alpha_cutoff, "coverage": round(maps.coverage, 6)}
    with atomic_path(folder / MANIFEST_FILE) as tmp:
        Path(tmp).write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest, notes


def _read(path: Path, channels: int) -> list[torch.Tensor]:
    return [torch.from_numpy(np.asarray(c, dtype=np.float32)).permute(2, 0, 1).contiguous()
            for c in read_mip_chain(path, channels, what="surface map")]


def read_surface_files(folder, manifest: dict | None = None) -> SurfaceMaps | None:
    """The :class:`SurfaceMaps` of an export ``folder`` from its manifest (default: its ``surface.json``;
    None when there is none). Coverage levels (training only) are not stored: they come back empty."""
    manifest = manifest if manifest is not None else read_surface_manifest(folder)
    if not manifest:
        return None
    folder = Path(folder)
    maps = SurfaceMaps(alpha_mode=manifest.get("alpha_mode", "opaque"), coverage=float(manifest.get("coverage", 1.0)))
    e, o = manifest.get("emission"), manifest.get("opacity")
    if e and "file" in e:
        maps.emission_levels = _read(folder / e["file"], 3)
    elif e and "constant" in e:
        maps.emission_constant = tuple(float(x) for x in e["constant"])
    if o and "file" in o:
        maps.opacity_levels = _read(folder / o["file"], 1)
    elif o and "constant" in o:
        maps.opacity_constant = float(o["constant"])
    return maps
