"""Export trained materials: latent EXRs, weights and the USD layer, all or nothing.

Output layout (``OUT`` is the conversion's output folder, ``<asset stem>_neural`` by
default; the layer sits beside it, so by default next to the input)::

    <asset folder>/
      <stem>.usda                      the input, never modified
      <stem>_neural.usda               the neural layer (OUT.parent / (OUT.name + ".usda"))
      <stem>_neural/                   OUT
        <material folder>/             training: checkpoint.pt, summary.json, curves, PNGs
          neural/                      export, replaced as a whole
            latents_0.exr ...          latent channels 0-3, 4-7, ... (half, RGBA, MIP chain, raw)
            weights.bin, weights.json  FP16 weights and their manifest
            NeuralMaterial_<name>.slang (+ .fp16.bin, .coopvec.bin), NeuralMaterial.slang,
            NeuralLayers.slang         generated shader module and runtime (mtlx2neural.codegen)
            export.json                source hash, metrics and FP16 notes of this export

Every file is first written into a staging folder beside the layer and moved into
place only when all of them were written (:mod:`.staging`); on any failure the
previous export, if any, stays as it was and nothing partial remains.
"""

from __future__ import annotations

import json
from pathlib import Path

from mtlx2neural.codegen import write_material_shader
from mtlx2neural.export.latents import write_latent_textures
from mtlx2neural.export.usd_writer import (
    ExportedMaterial,
    KeptMaterials,
    write_neural_layer,
)
from mtlx2neural.formats.weights import write_weights
from mtlx2neural.staging import Staging

EXPORT_FOLDER = "neural"


def layer_path(out) -> Path:
    """The neural layer for the output folder ``out``: a sibling ``<out name>.usda``."""
    out = Path(out).resolve()
    return out.parent / f"{out.name}.usda"


def metrics(summary: dict, preset: str) -> dict:
    """The ``neural:metrics:*`` values from a training summary."""
    return {"flip": summary.get("flip_mean", float("nan")), "iterations": summary.get("steps", 0),
            "preset": preset, "device": summary.get("device_name") or summary.get("device", ""),
            "train_seconds": summary.get("train_seconds", summary.get("seconds", 0.0))}


def export_material(model, summary: dict, staged: Path, final: Path, preset: str) -> ExportedMaterial:
    """Write ``model``'s latents and weights into ``staged``; paths in the result point at ``final``."""
    textures, notes = write_latent_textures(list(model.latents.levels), staged)
    manifest, wnotes = write_weights(model, staged)
    write_material_shader(model, staged, summary["material"])  # NeuralMaterial_<name>.slang + runtime
    m = ExportedMaterial(
        name=summary["material"], material=summary.get("mtlx_material", summary["material"]), folder=final,
        latent_textures=[final / p.name for p in textures], weights=final / manifest["file"],
        manifest=final / "weights.json", architecture=manifest["architecture"],
        source_hash=summary.get("source_hash", ""), metrics=metrics(summary, preset), notes=notes + wnotes)
    record = {"material": m.name, "source_hash": m.source_hash, "metrics": m.metrics, "notes": m.notes,
              "latent_textures": [p.name for p in m.latent_textures], "weights": m.weights.name,
              "manifest": m.manifest.name}
    (staged / "export.json").write_text(json.dumps(record, indent=2) + "\n")
    return m


def export_asset(asset, trained: list[tuple], out, preset: str, usda=None, keep: KeptMaterials | None = None,
                 tool_version: str = "") -> tuple[Path, list[ExportedMaterial]]:
    """Export every ``(model, summary, material folder)`` of ``trained`` and write the layer.

    ``usda`` defaults to :func:`layer_path` of ``out``. ``keep``: materials of the
    previous layer at ``usda`` to carry over (:func:`~.usd_writer.write_neural_layer`).
    Returns (layer path, exported materials).
    """
    usda = Path(usda).resolve() if usda else layer_path(out)
    exported = []
    with Staging(usda.parent) as st:
        for model, summary, folder in trained:
            final = Path(folder).resolve() / EXPORT_FOLDER
            exported.append(export_material(model, summary, st.stage(final), final, preset))
        write_neural_layer(asset, exported, st.stage_file(usda), anchor=usda, keep=keep, tool_version=tool_version)
    return usda, exported
