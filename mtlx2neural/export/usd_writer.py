"""The neural USD layer: NeuralMaterialAPI, a NeuralBSDF shader and the ``neuralMaterial`` variant set.

USD input: the new layer **sublayers the input** (a path relative to the new layer;
for an open stage with unsaved or in-memory edits, the input is the stage's flattened
snapshot that the conversion wrote into its output folder, :mod:`mtlx2neural.scene.snapshot`)
and authors only ``over`` opinions on the converted Material prims (also on those
that come from a referenced ``.mtlx`` file, which usd-core cannot compose but a USD
build with usdMtlx does), so binding,
geometry and the original networks come from the input unchanged. The root layer's
stage metadata (upAxis, metersPerUnit, defaultPrim, time codes...) is copied, since
USD reads stage metadata from the root layer only.

``.mtlx`` input (usd-core cannot compose ``.mtlx`` files, so the layer references
nothing): ``/Materials`` holds one Material per converted material, whose original
network stays MaterialX: a Shader ``MaterialX`` whose implementation is the
``.mtlx`` file (``info:implementationSource = "sourceAsset"``,
``info:mtlx:sourceAsset``, sub-identifier the surfacematerial's name) feeds
``outputs:mtlx:surface``. It is authored in the ``original`` variant, so that the
``neural`` variant's own ``outputs:mtlx:surface`` is not shadowed.

A measured BRDF (a MERL ``.binary`` table) is written as ``.mtlx`` input is, under ``/Materials``, except
that its variant set has only the ``neural`` variant: the table has no network USD could show.

Per converted Material, everything neural lives in the ``neural`` variant of the
variant set ``neuralMaterial`` (selected by default):

- the applied ``NeuralMaterialAPI`` and its ``neural:*`` attributes (``neural:metrics:flip``: the
  neural material's mean HDR FLIP against the reference on the analytic views;
  ``neural:metrics:flipInScene``: the same on the stage's own bound meshes, with its camera and
  lights, for a USD input bound to meshes (the figure ``--max-error`` checks then);
  ``neural:metrics:previewFlip``: the UsdPreviewSurface fallback's, so a pipeline sees what each
  render context costs); for a material that emits or is not opaque (``ExportedMaterial.surface``),
  its emission and opacity: ``neural:emissionTexture`` (``emission.exr``) or ``neural:emissionColor``
  (the constant radiance; (1, 1, 1), the texture's scale, beside a texture), ``neural:opacityTexture``
  (``opacity.exr``) or ``neural:opacity`` (the constant), ``neural:alphaMode`` (``mask``: alpha-tested
  at ``neural:alphaCutoff``; ``blend``), only what the material has (``_surface_attributes``);
- ``outputs:neural:surface``: the ``NeuralBSDF`` Shader (with a ``UsdPrimvarReader_float2`` for
  ``st``), read by this project (:func:`~mtlx2neural.export.load.load_neural`);
- ``outputs:mtlx:surface``: the MaterialX network of the material's ``NeuralMaterial_<ident>.mtlx``
  (:mod:`.usd_mtlx_network`), for Hydra Storm and other renderers built with UsdMtlx; with the
  emission on the ``ND_surface`` node's ``edf`` and the opacity on its ``opacity``;
- ``outputs:surface`` (universal): a ``UsdPreviewSurface`` (Shader ``NeuralPreview``) of the
  analytic baseline (Lambert + GGX fitted to the reference) and its baked textures, for tools
  that read neither MaterialX nor custom shaders (Storm without UsdMtlx, Blender's importer,
  RealityKit / QuickLook), with the emission on ``emissiveColor`` and the opacity on ``opacity``
  and ``opacityThreshold`` (0.5 for a cut-out, 0 for a blend).

The emission and opacity maps are asset paths relative to the layer, as the latent textures are.

The ``original`` variant holds nothing else (a variant cannot block an opinion authored outside
it, so the neural opinions must not be authored outside), with one exception. For a USD input,
the input's opinions are local to the layer stack and stronger than any variant's: a terminal
output that the input's Material connects itself (CarPaint's ``outputs:mtlx:surface``, Plastic's
``outputs:surface`` in ``samples/layered_spheres.usda``) would shadow the variant's network. For
each such output that the ``neural`` variant replaces, the layer connects the Material's output,
outside the variants, to a ``NeuralSwitch`` NodeGraph that each variant defines: ``neural`` routes
it to the neural network, ``original`` to exactly what the input connected
(:mod:`.usd_switch`, which also cites why UsdShade and Hydra follow it). So selecting
``original`` gives back the input's *resolved* networks (``ComputeSurfaceSource`` of every render
context returns the input's shader and output) and the input's prims and attributes unchanged,
although those switched Material outputs now name the switch rather than the shader.
Asset paths are relative to the layer (``./...``).

Viewing the MaterialX network (a USD build with UsdMtlx, e.g. usdview or a DCC on Hydra Storm):
set ``PXR_MTLX_PLUGIN_SEARCH_PATHS`` to the folders holding the ``NeuralMaterial_<ident>.mtlx``
files (``OUT/<material folder>/neural/materialx``; several joined with ``:``, ``;`` on Windows), which the
layer lists in its record (``mtlxPluginSearchPaths``, relative to the layer) and in its
documentation string. ``PXR_MTLX_STDLIB_SEARCH_PATHS`` is needed only when the build does not find
MaterialX's standard libraries itself. Each ``.mtlx`` finds its ``.glsl`` / ``.slang``
implementation beside it and its latent textures one folder up; in the layer, the network's
latent inputs are asset paths relative to the layer, which Hydra resolves itself.

The layer records what it holds in its ``customLayerData`` under
:data:`RECORD_KEY`: the input it was written for (``source``, relative to the
layer), the tool version, per material name its prim, source hash, material folder and
``.mtlx`` document (``mtlxDocument``), and the folders of those documents
(``mtlxPluginSearchPaths``), and the materials a run skipped because they could not be
converted, with the reason (``skippedMaterials``). That record is how a later run recognises the layer as this
tool's (:mod:`.outputs`) and how a ``--material`` run keeps the other materials:
their prim specs are copied unchanged from the previous layer (``keep``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from mtlx2neural import usd_schema
from mtlx2neural.baseline.analytic_model import author_preview_surface
from mtlx2neural.codegen.materialx_node import atlas_file_names
from mtlx2neural.export.usd_mtlx_network import author_mtlx_network
from mtlx2neural.export.usd_switch import (
    author_switch,
    connect_material_to_switch,
    input_connections,
    take_variant_connections,
)
from mtlx2neural.formats import FORMAT_VERSION

VARIANT_SET = "neuralMaterial"
NEURAL, ORIGINAL = "neural", "original"
SHADER_ID = "NeuralBSDF"
API = "NeuralMaterialAPI"
MTLX_SCOPE = "/Materials"
MEASURED_SUFFIXES = (".binary",)
"""Inputs that are measured BRDFs (MERL tables): their Materials hold only the ``neural`` variant."""
RECORD_KEY = "mtlx2neural"
"""``customLayerData`` key of the layer's record (module docstring)."""
PREVIEW_PREFIX = "NeuralPreview"
"""Name of the UsdPreviewSurface fallback's Shader (and prefix of its texture readers)."""
LEGACY_DOC_PREFIX = "mtlx2neural neural materials for"
"""How layers written before the record began their documentation string."""


_schema_tried = False


def register_schema() -> None:
    """Register the NeuralMaterialAPI / NeuralBSDF plugin once per process (best effort: the layer
    is written and read the same way without it; USD only knows the schema when this runs
    before its schema registry is first built)."""
    global _schema_tried
    if _schema_tried:
        return
    _schema_tried = True
    try:

        usd_schema.register()
    except Exception:  # noqa: BLE001, S110 - e.g. the plugin folder is missing from an install
        pass


@dataclass
class ExportedMaterial:
    """One material's exported files (final, absolute paths) and what the USD layer records about it."""

    name: str
    """USD Material prim path, or the MaterialX surfacematerial name for ``.mtlx`` input."""
    material: str
    """The surfacematerial node name."""
    folder: Path
    latent_textures: list[Path]
    weights: Path
    manifest: Path
    architecture: dict
    """``weights.architecture(model)``."""
    source_hash: str
    metrics: dict
    """flip (mean HDR FLIP), iterations, preset, device, train_seconds."""
    notes: list[str] = field(default_factory=list)
    """FP16 range-check notes, and what the layer could not control (a Material usd-core cannot compose)."""
    mtlx_document: Path | None = None
    """``NeuralMaterial_<ident>.mtlx`` (:mod:`mtlx2neural.codegen.materialx_node`): with it the
    ``neural`` variant holds the MaterialX network (:mod:`.usd_mtlx_network`)."""
    preview: dict | None = None
    """``{"textures": {UsdPreviewSurface input: Path}, "ior": float}``, the analytic baseline baked
    (:func:`mtlx2neural.baseline.analytic_model.write_preview_textures`): with it the ``neural``
    variant's universal ``outputs:surface`` is a UsdPreviewSurface of them."""
    quality: dict | None = None
    """The quality gate's verdict (``MaterialRecord.quality``): a flagged material under the ``original``
    policy gets its ``original`` variant selected; ``neural:quality`` records it either way."""
    surface: dict | None = None
    """The emission and opacity maps' manifest (:func:`mtlx2neural.export.surface_files.write_surface_files`,
    file names relative to ``folder``), or None when the material emits nothing and is opaque."""


def relative_asset(path, anchor_dir) -> str:
    """``path`` relative to ``anchor_dir`` as a USD anchored asset path (``./x`` or ``../x``)."""
    try:
        rel = os.path.relpath(path, anchor_dir).replace(os.sep, "/")
    except ValueError:  # another drive: keep it absolute
        return Path(path).as_posix()
    return rel if rel.startswith("../") else "./" + rel


def _define_shader(stage, path):
    """A ``def Shader`` at ``path`` whose missing ancestors are authored as ``over``, not ``def``
    (``UsdShade.Shader.Define`` would define them, which matters under a Material that only a
    usdMtlx-enabled USD composes)."""
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Sdf, UsdShade

    prim = stage.OverridePrim(path)
    prim.SetSpecifier(Sdf.SpecifierDef)
    prim.SetTypeName("Shader")
    return UsdShade.Shader(prim)


def _set(prim, name: str, type_name, value) -> None:
    prim.CreateAttribute(name, type_name, custom=False).Set(value)


def _api_attributes(prim, m: ExportedMaterial, rel) -> None:
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Gf, Sdf, Vt

    a, t = m.architecture, Sdf.ValueTypeNames
    prim.AddAppliedSchema(API)
    _set(prim, "neural:version", t.Int, FORMAT_VERSION)
    _set(prim, "neural:latentChannels", t.Int, a["latent_channels"])
    _set(prim, "neural:frameCount", t.Int, a["frames"])
    _set(prim, "neural:decoderLayers", t.IntArray, Vt.IntArray(a["decoder_hidden"]))
    _set(prim, "neural:samplerLayers", t.IntArray, Vt.IntArray(a["sampler_hidden"]))
    _set(prim, "neural:encoderLayers", t.IntArray, Vt.IntArray(a["encoder_hidden"]))
    _set(prim, "neural:activation", t.Token, a["activation"])
    _set(prim, "neural:outputActivation", t.Token, a["output_activation"])
    _set(prim, "neural:latentTextures", t.AssetArray,
         Sdf.AssetPathArray([Sdf.AssetPath(rel(p)) for p in m.latent_textures]))
    _set(prim, "neural:latentResolution", t.Int2, Gf.Vec2i(*a["latent_resolution"]))
    if a.get("udim_tiles"):  # a UDIM material: latentTextures are <UDIM> patterns, one file per tile
        _set(prim, "neural:udimTiles", t.IntArray, Vt.IntArray([int(u) for u in a["udim_tiles"]]))
    _set(prim, "neural:weights", t.Asset, Sdf.AssetPath(rel(m.weights)))
    _set(prim, "neural:weightsManifest", t.Asset, Sdf.AssetPath(rel(m.manifest)))
    _set(prim, "neural:weightsLayout", t.Token, "row_major_fp16")
    _set(prim, "neural:proxyType", t.Token, a["proxy_type"])
    _set(prim, "neural:sourceHash", t.String, m.source_hash)
    x = m.metrics
    _set(prim, "neural:metrics:flip", t.Float, float(x["flip"]))
    if x.get("preview_flip") is not None:  # the UsdPreviewSurface fallback's mean HDR FLIP
        _set(prim, "neural:metrics:previewFlip", t.Float, float(x["preview_flip"]))
    if x.get("flip_in_scene") is not None:  # on the stage's own meshes, camera and lights (USD input)
        _set(prim, "neural:metrics:flipInScene", t.Float, float(x["flip_in_scene"]))
    _set(prim, "neural:metrics:iterations", t.Int, int(x["iterations"]))
    _set(prim, "neural:metrics:preset", t.Token, str(x["preset"]))
    _set(prim, "neural:metrics:device", t.String, str(x["device"]))
    _set(prim, "neural:metrics:trainSeconds", t.Float, float(x["train_seconds"]))
    if m.quality is not None:  # the quality gate (pipeline.quality): passed, or flagged with its reasons
        _set(prim, "neural:quality", t.Token, "flagged" if m.quality["flagged"] else "passed")
        if m.quality["flagged"]:
            _set(prim, "neural:qualityReasons", t.StringArray, Vt.StringArray(list(m.quality["reasons"])))
    _surface_attributes(prim, surface_assets(m, rel))


def surface_assets(m: ExportedMaterial, rel) -> dict | None:
    """``m.surface`` (None: the material emits nothing and is opaque) with each map's ``file`` as the layer
    states it (``rel`` of the file in ``m.folder``), for :mod:`.usd_mtlx_network` and the preview."""
    if not m.surface:
        return None
    out = dict(m.surface)
    for key in ("emission", "opacity"):
        entry = m.surface.get(key)
        if entry and "file" in entry:
            out[key] = {**entry, "file": rel(Path(m.folder) / entry["file"])}
    return out


def _surface_attributes(prim, surface: dict | None) -> None:
    """The NeuralMaterialAPI's emission and opacity attributes (module docstring) from ``surface``
    (:func:`surface_assets`), only what the material has."""
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Gf, Sdf

    t = Sdf.ValueTypeNames
    emission, opacity = (surface or {}).get("emission"), (surface or {}).get("opacity")
    if emission and "file" in emission:
        _set(prim, "neural:emissionTexture", t.Asset, Sdf.AssetPath(emission["file"]))
        _set(prim, "neural:emissionColor", t.Color3f, Gf.Vec3f(1.0, 1.0, 1.0))  # the texture's scale
    elif emission:
        _set(prim, "neural:emissionColor", t.Color3f, Gf.Vec3f(*(float(x) for x in emission["constant"])))
    if opacity:
        if "file" in opacity:
            _set(prim, "neural:opacityTexture", t.Asset, Sdf.AssetPath(opacity["file"]))
        else:
            _set(prim, "neural:opacity", t.Float, float(opacity["constant"]))
        _set(prim, "neural:alphaMode", t.Token, surface["alpha_mode"])
        if surface["alpha_mode"] == "mask":
            _set(prim, "neural:alphaCutoff", t.Float, float(surface.get("alpha_cutoff") or 0.5))


def _neural_shader(stage, material, m: ExportedMaterial, rel) -> None:
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Sdf

    t = Sdf.ValueTypeNames
    path = material.GetPath()
    shader = _define_shader(stage, path.AppendChild(SHADER_ID))
    shader.CreateIdAttr(SHADER_ID)
    for k, p in enumerate(m.latent_textures):
        shader.CreateInput(f"latentTexture{k}", t.Asset).Set(Sdf.AssetPath(rel(p)))
    shader.CreateInput("weights", t.Asset).Set(Sdf.AssetPath(rel(m.weights)))
    shader.CreateInput("weightsManifest", t.Asset).Set(Sdf.AssetPath(rel(m.manifest)))
    reader = _define_shader(stage, path.AppendChild("NeuralStReader"))
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", t.String).Set("st")
    st = reader.CreateOutput("result", t.Float2)
    shader.CreateInput("st", t.Float2).ConnectToSource(st)
    out = shader.CreateOutput("surface", t.Token)
    material.CreateSurfaceOutput("neural").ConnectToSource(out)


def _replaced(m: ExportedMaterial) -> list[str]:
    """The Material's terminal outputs that the ``neural`` variant replaces: ``outputs:mtlx:surface``
    when ``m`` has a MaterialX node, the universal ``outputs:surface`` when it has a preview."""
    return [o for o, have in (("outputs:mtlx:surface", m.mtlx_document), ("outputs:surface", m.preview))
            if have is not None]


def _neural_extras(stage, material, m: ExportedMaterial, rel) -> None:
    """The MaterialX network and the UsdPreviewSurface fallback of ``m``, where it has them, with its
    emission and opacity."""
    if m.mtlx_document is not None:
        # The node reads its latent atlases beside its document (codegen.materialx_node), one per texture.
        atlases = [m.mtlx_document.parent / f for f in atlas_file_names(len(m.latent_textures))]
        author_mtlx_network(stage, material, m.name, [rel(p) for p in atlases], surface_assets(m, rel))
    if m.preview is not None:
        author_preview_surface(stage, material.GetPath(), {k: rel(p) for k, p in m.preview["textures"].items()},
                               m.preview["ior"], prefix=PREVIEW_PREFIX, surface=surface_assets(m, rel))


def _mtlx_original(stage, material, m: ExportedMaterial, asset: Path, rel) -> None:
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Sdf, UsdShade

    shader = UsdShade.Shader.Define(stage, material.GetPath().AppendChild("MaterialX"))
    shader.SetSourceAsset(Sdf.AssetPath(rel(asset)), "mtlx")
    shader.SetSourceAssetSubIdentifier(m.material, "mtlx")
    out = shader.CreateOutput("out", Sdf.ValueTypeNames.Token)
    material.CreateSurfaceOutput("mtlx").ConnectToSource(out)


def _mtlx_prim_paths(materials, reserved=()) -> list[str]:
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Tf

    names, paths = {p.rsplit("/", 1)[-1] for p in reserved}, []
    for m in materials:
        base = Tf.MakeValidIdentifier(m.name)
        name, i = base, 1
        while name in names:
            name, i = f"{base}_{i}", i + 1
        names.add(name)
        paths.append(f"{MTLX_SCOPE}/{name}")
    return paths


@dataclass
class KeptMaterials:
    """Materials of a previous layer to carry over unchanged (a ``--material`` run)."""

    layer: Path
    """The previous layer (at the same path as the new one, so its relative paths stay valid)."""
    entries: dict[str, dict]
    """Material name -> its record entry (``prim``, ``sourceHash``, ``folder``)."""


def _copy_kept(old_path: Path, layer, kept: dict[str, dict]) -> None:
    """Copy each kept material's prim spec from the previous layer (ancestors as ``over``)."""
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Sdf

    old = Sdf.Layer.OpenAsAnonymous(str(old_path))  # not the registry's copy, which may be stale
    for entry in kept.values():
        path = Sdf.Path(entry["prim"])
        if old is None or not old.GetPrimAtPath(path):
            continue
        parent = path.GetParentPath()
        if parent != Sdf.Path.absoluteRootPath and not layer.GetPrimAtPath(parent):
            Sdf.CreatePrimInLayer(layer, parent)
            if str(parent) == MTLX_SCOPE:  # the .mtlx input's scope is defined, as the writer defines it
                spec = layer.GetPrimAtPath(parent)
                spec.specifier, spec.typeName = Sdf.SpecifierDef, "Scope"
        Sdf.CopySpec(old, path, layer, path)


def write_neural_layer(asset, materials: list[ExportedMaterial], out_usda, anchor=None,
                       keep: KeptMaterials | None = None, tool_version: str = "",
                       skipped: dict[str, str] | None = None, shared_network: dict | None = None) -> Path:
    """Write the neural layer for ``materials`` of ``asset`` to ``out_usda``.

    ``anchor`` is where the layer will finally live (default ``out_usda``): relative
    asset and sublayer paths are computed from its folder, so the layer can be written
    into a staging folder first. ``keep``: materials of the previous layer at
    ``anchor`` whose prim specs are copied over unchanged (those not in ``materials``).
    ``skipped``: material name -> why it could not be converted; recorded as the
    record's ``skippedMaterials`` (those materials keep their original network only).
    ``shared_network``: ``{"folder", "module", "materials"}`` of a ``--network scene`` conversion, recorded as
    the record's ``sharedNetwork`` (paths relative to the layer).
    Returns ``out_usda``. The input is only read.
    """
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Sdf, Usd, UsdGeom, UsdShade, Vt

    asset = Path(asset).resolve()
    out_usda = Path(out_usda)
    anchor_dir = Path(anchor or out_usda).resolve().parent

    def rel(p):
        return relative_asset(Path(p).resolve(), anchor_dir)

    layer = Sdf.Layer.CreateAnonymous(".usda")
    is_mtlx = asset.suffix.lower() == ".mtlx"
    # a MERL table, or a folder of them: no original network to offer
    measured = asset.suffix.lower() in MEASURED_SUFFIXES or asset.is_dir()
    standalone = is_mtlx or measured  # no USD input to sublayer: the layer defines its Materials
    kept = {k: v for k, v in (keep.entries if keep else {}).items() if k not in {m.name for m in materials}}
    if standalone:
        paths = _mtlx_prim_paths(materials, [e["prim"] for e in kept.values()])
        stage = Usd.Stage.Open(layer)
        UsdGeom.Scope.Define(stage, MTLX_SCOPE)
        stage.SetDefaultPrim(stage.GetPrimAtPath(MTLX_SCOPE))
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, UsdGeom.LinearUnits.meters)
    else:
        # The file on disk, not the registry's copy (stale or with unsaved edits when the same
        # process opened it before, e.g. a rewritten stage snapshot); only its metadata is needed.
        src = Sdf.Layer.OpenAsAnonymous(str(asset), True)
        if src is None:
            raise ValueError(f"{asset}: cannot read the input layer the neural layer sublayers")
        info = src.pseudoRoot
        for key in info.ListInfoKeys():
            if key not in ("subLayers", "subLayerOffsets", "documentation", "comment"):
                layer.pseudoRoot.SetInfo(key, info.GetInfo(key))
        layer.subLayerPaths.append(str(asset))  # absolute while authoring, relative when saved
        paths = [m.name for m in materials]
        mask = Usd.StagePopulationMask(paths) if paths else Usd.StagePopulationMask.All()
        stage = Usd.Stage.OpenMasked(layer, mask, load=Usd.Stage.LoadNone)
    stage.SetEditTarget(stage.GetRootLayer())
    for m, path in zip(materials, paths):
        if standalone:
            material = UsdShade.Material.Define(stage, path)
            material.GetPrim().SetCustomDataByKey("mtlx2neural:material", m.material)
        else:
            prim = stage.GetPrimAtPath(path)
            if prim and prim.IsDefined() and not prim.IsA(UsdShade.Material):
                raise ValueError(f"{asset}: {path} is a {prim.GetTypeName() or 'typeless prim'}, not a Material; "
                                 f"cannot write its neural material")
            # A Material that usd-core cannot compose (from a referenced .mtlx file, which needs the
            # usdMtlx plugin) is not on this stage: the over still applies where usdMtlx composes it.
            material = UsdShade.Material(prim if prim else stage.OverridePrim(path))
        # what the input itself connects, read before anything is authored on the Material (.usd_switch)
        switched = {} if standalone else input_connections(material, _replaced(m))
        if not standalone and not material.GetPrim().IsDefined() and _replaced(m):
            m.notes.append(f"{m.name}: usd-core cannot compose this Material, so its own terminal outputs are "
                           f"unknown; where a usdMtlx build composes outputs it connects, they shadow the "
                           f"'{NEURAL}' variant's networks")
        vset = material.GetPrim().GetVariantSets().AddVariantSet(VARIANT_SET)
        if not measured:  # a measured table has no USD or MaterialX network of its own
            vset.AddVariant(ORIGINAL)
        vset.AddVariant(NEURAL)
        if is_mtlx or switched:
            vset.SetVariantSelection(ORIGINAL)
            with vset.GetVariantEditContext():
                if is_mtlx:  # in the original variant: an opinion outside the variants would shadow the neural one
                    _mtlx_original(stage, material, m, asset, rel)
                if switched:  # the input's own connections, through the switch
                    author_switch(stage, material, switched)
        vset.SetVariantSelection(NEURAL)
        with vset.GetVariantEditContext():
            _api_attributes(material.GetPrim(), m, rel)
            _neural_shader(stage, material, m, rel)
            _neural_extras(stage, material, m, rel)
            if switched:
                author_switch(stage, material, take_variant_connections(stage, material, list(switched)))
        if switched:  # outside the variants: stronger than the sublayered input's opinion
            connect_material_to_switch(material, list(switched))
        if m.quality and m.quality["flagged"] and m.quality["policy"] == "original" and not measured:
            vset.SetVariantSelection(ORIGINAL)  # a flagged model is not the default render (pipeline.quality)
    del stage  # a live stage would recompose (and warn) when the sublayer path becomes relative
    if kept:
        _copy_kept(keep.layer, layer, kept)
    if not standalone:
        layer.subLayerPaths[0] = rel(asset)
    entries = {m.name: {"prim": str(p), "sourceHash": m.source_hash, "folder": rel(Path(m.folder).parent)}
               for m, p in zip(materials, paths)}
    for m in materials:
        if m.mtlx_document is not None:
            entries[m.name]["mtlxDocument"] = rel(m.mtlx_document)
    entries.update(kept)
    record = {"formatVersion": FORMAT_VERSION, "tool": f"mtlx2neural {tool_version}".strip(), "source": rel(asset),
              "materials": {k: entries[k] for k in sorted(entries)}}
    if skipped:
        record["skippedMaterials"] = {k: skipped[k] for k in sorted(skipped)}
    if shared_network:
        record["sharedNetwork"] = {"folder": rel(shared_network["folder"]), "module": rel(shared_network["module"]),
                                   "materials": Vt.StringArray(list(shared_network["materials"]))}
    documents = sorted(e["mtlxDocument"] for e in entries.values() if "mtlxDocument" in e)
    if documents:  # what a UsdMtlx viewer must find (module docstring)
        record["mtlxPluginSearchPaths"] = Vt.StringArray(sorted({d.rsplit("/", 1)[0] for d in documents}))
    layer.customLayerData = {**dict(layer.customLayerData), RECORD_KEY: record}
    variants = f"'{NEURAL}' only (a measured table has no network USD can show)" if measured else \
        f"'{NEURAL}' (default) or '{ORIGINAL}'"
    layer.documentation = (f"{LEGACY_DOC_PREFIX} {asset.name}: " + ", ".join(sorted(entries))
                           + f". Variant set '{VARIANT_SET}' on each Material: {variants}.")
    if documents:
        layer.documentation += (" MaterialX viewers: list the folders of " + ", ".join(documents)
                                + " (relative to this layer) in PXR_MTLX_PLUGIN_SEARCH_PATHS.")
    if not layer.Export(str(out_usda)):
        raise OSError(f"{out_usda}: cannot write the USD layer")
    return out_usda
