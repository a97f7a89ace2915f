"""Rebuild a neural material from an exported USD layer and its files alone (no checkpoint).

``load_neural(path, material)`` opens the layer, selects the ``neural`` variant of
the Material (in the session layer, so nothing is written), reads the
``neural:*`` attributes, the weights manifest and binary, and the latent EXR MIP
chains (for a UDIM material, ``<UDIM>`` patterns read tile by tile for the tiles the manifest
lists, ``architecture.udim_tiles``), and builds a :class:`NeuralMaterial` in float32 holding exactly the stored
FP16 values. Its ``eval``/``sample``/``pdf`` therefore equal those of the trained
model with its latents and weights rounded to FP16 (the encoder, used only in
training, is not exported and is left untrained).
"""

from __future__ import annotations

from pathlib import Path

import torch

from mtlx2neural.errors import InputError
from mtlx2neural.export.latents import read_latent_textures
from mtlx2neural.export.surface_files import read_surface_files
from mtlx2neural.export.usd_writer import API, NEURAL, VARIANT_SET, register_schema
from mtlx2neural.formats import FORMAT_VERSION
from mtlx2neural.formats.latent_codec import codec_from_architecture
from mtlx2neural.formats.weights import analytic_cosine_of, read_weights
from mtlx2neural.model.checkpoint import model_arguments
from mtlx2neural.model.neural_material import NeuralMaterial


class ExportedNeuralMaterial(NeuralMaterial):
    """A :class:`NeuralMaterial` read back from USD (a :class:`~mtlx2neural.contract.Material` like it);
    it only adds its USD information (``usd_info``) to :meth:`describe`."""

    usd_info: dict = {}

    def describe(self) -> dict:
        """:meth:`NeuralMaterial.describe` plus where it came from: ``layer``, ``material`` (prim path),
        ``source_hash``, ``latent_textures``, ``weights``, the manifest's ``architecture`` and ``notes``."""
        return {**super().describe(), **self.usd_info}


def applied_schemas(prim) -> list[str]:
    """The API schema names applied to ``prim``, including ones whose plugin is not registered
    (``GetAppliedSchemas`` lists registered schemas only)."""
    listop = prim.GetMetadata("apiSchemas")
    return list(listop.GetAddedOrExplicitItems()) if listop else []


def neural_prims(stage):
    """Prims with the API or the variant set; all prims, since a Material from a referenced ``.mtlx``
    file (which usd-core cannot compose) is only an ``over`` here."""
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Usd

    return [p for p in Usd.PrimRange.Stage(stage, Usd.PrimAllPrimsPredicate)
            if API in applied_schemas(p) or p.GetVariantSets().HasVariantSet(VARIANT_SET)]


def _choose(path, prims, material: str | None):
    def names(p):
        return {str(p.GetPath()), p.GetName(), p.GetCustomDataByKey("mtlx2neural:material")} - {None}

    if material is None:
        if len(prims) == 1:
            return prims[0]
        listing = ", ".join(str(p.GetPath()) for p in prims) or "none"
        raise InputError(f"{path}: {len(prims)} neural materials ({listing}); choose one with material=...")
    hits = [p for p in prims if material in names(p) or "/" + material.lstrip("/") in names(p)]
    if len(hits) != 1:
        listing = ", ".join(str(p.GetPath()) for p in prims) or "none"
        what = "is ambiguous" if hits else "matches no neural material"
        raise InputError(f"{path}: {material!r} {what}; neural materials: {listing}")
    return hits[0]


def _get(prim, name: str, path):
    attr = prim.GetAttribute(name)
    if not attr or not attr.HasAuthoredValue():
        raise InputError(f"{path}: {prim.GetPath()} has no {name}; re-export it with mtlx2neural")
    return attr.Get()


def _resolved(asset_path, prim, name: str, path) -> Path:
    """The file ``asset_path`` names: USD's resolved path, else (a file that does not exist) the
    authored path anchored at the layer's folder, so that the reader's error names the file. A
    ``<UDIM>`` pattern (which USD leaves unresolved) is anchored at the layer that authored it
    (``UsdShade.UdimUtils``), the token kept."""
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import UsdShade

    p = asset_path.resolvedPath
    if p:
        return Path(p)
    if UsdShade.UdimUtils.IsUdimIdentifier(asset_path.path):
        stack = prim.GetAttribute(name).GetPropertyStack()
        found = UsdShade.UdimUtils.ResolveUdimPath(asset_path.path, stack[0].layer) if stack else ""
        if found:
            return Path(found)
    if not asset_path.path:
        raise InputError(f"{path}: {prim.GetPath()}.{name} is empty; re-export it with mtlx2neural")
    return (Path(path).resolve().parent / asset_path.path).resolve()


def _read_weights(manifest_file: Path, weights_file: Path, prim, path):
    """(manifest, tensors, architecture, the architecture's shape fields) of the exported weights; a
    missing file is an :class:`InputError` naming it (a malformed one raises KeyError, TypeError or
    ValueError, which the caller names it for)."""
    for f, what, attr in ((manifest_file, "weights manifest", "neural:weightsManifest"),
                          (weights_file, "weights", "neural:weights")):
        if not f.is_file():
            raise InputError(f"{f}: the {what} file that {path} names ({prim.GetPath()}.{attr}) "
                             f"{'is a directory' if f.is_dir() else 'does not exist'}; keep the exported "
                             f"folder next to the layer, or export the material again")
    manifest, state = read_weights(manifest_file, weights_file)  # InputError: unreadable, size, sha256
    arch = manifest["architecture"]
    return manifest, state, arch, {"latent_channels": arch["latent_channels"], "frames": arch["frames"],
                                   "decoder_hidden": list(arch["decoder_hidden"])}


def load_neural(path, material: str | None = None, device: str = "cpu") -> ExportedNeuralMaterial:
    """The neural material ``material`` (prim path, prim name or MaterialX name; optional when the layer
    holds one) of the exported layer ``path``, in eval mode on ``device``."""
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Usd

    register_schema()  # the attributes are read the same way without it
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file; give the .usda that `mtlx2neural ASSET` wrote")
    stage = Usd.Stage.Open(str(path), load=Usd.Stage.LoadNone)
    if stage is None:
        raise InputError(f"{path}: cannot open the USD layer")
    prim = _choose(path, neural_prims(stage), material)
    vset = prim.GetVariantSets().GetVariantSet(VARIANT_SET)
    if vset and vset.GetVariantSelection() != NEURAL:
        with Usd.EditContext(stage, stage.GetSessionLayer()):
            vset.SetVariantSelection(NEURAL)
        prim = stage.GetPrimAtPath(prim.GetPath())
    version = _get(prim, "neural:version", path)
    if version != FORMAT_VERSION:
        raise InputError(f"{path}: {prim.GetPath()} has neural:version {version}; this mtlx2neural reads "
                         f"version {FORMAT_VERSION}")
    channels = int(_get(prim, "neural:latentChannels", path))
    manifest_file = _resolved(_get(prim, "neural:weightsManifest", path), prim, "neural:weightsManifest", path)
    weights_file = _resolved(_get(prim, "neural:weights", path), prim, "neural:weights", path)
    textures = [_resolved(a, prim, "neural:latentTextures", path) for a in _get(prim, "neural:latentTextures", path)]
    try:
        manifest, state, arch, shape = _read_weights(manifest_file, weights_file, prim, path)
    except (KeyError, TypeError, ValueError) as exc:  # tensor entries that do not fit the binary
        raise InputError(f"{manifest_file}: malformed weights manifest ({type(exc).__name__}: {exc}); "
                         f"export the material again") from None
    checks = {"neural:latentChannels": (channels, shape["latent_channels"]),
              "neural:frameCount": (int(_get(prim, "neural:frameCount", path)), shape["frames"]),
              "neural:decoderLayers": (list(_get(prim, "neural:decoderLayers", path)), shape["decoder_hidden"])}
    for name, (usd_value, file_value) in checks.items():
        if usd_value != file_value:
            raise InputError(f"{path}: {prim.GetPath()}.{name} = {usd_value} but {manifest_file} says "
                             f"{file_value}; the layer and its files are from different exports")
    tiles = arch.get("udim_tiles")  # a UDIM material: the tiles of its <UDIM> latent textures
    try:
        codec = codec_from_architecture(arch)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{manifest_file}: malformed latent format entries ({type(exc).__name__}: {exc}); "
                         f"export the material again") from None
    # A missing tile's file: InputError naming it. Block-compressed latents are decoded here, so the model
    # holds (and reads as stored) exactly the values a GPU samples from them.
    levels = read_latent_textures(textures, channels, tiles, codec=codec)
    for k, lv in enumerate(levels):
        state[f"latents.levels.{k}"] = lv
    if tiles:
        state["latents.tiles"] = torch.tensor([int(t) for t in tiles], dtype=torch.long)
    state["encoder.net.0.weight"] = torch.zeros(1, 1)  # not exported: build a placeholder encoder
    args = model_arguments(state, {"decoder": tuple(arch["decoder_hidden"])})
    args["in_dim"] = 0
    args["analytic_cosine"] = analytic_cosine_of(arch, manifest_file)
    del state["encoder.net.0.weight"]
    try:
        model = ExportedNeuralMaterial(**args)
        missing, unexpected = model.load_state_dict(state, strict=False)
    except (RuntimeError, ValueError, KeyError) as exc:
        raise InputError(f"{path}: {prim.GetPath()}: the exported files do not form a NeuralMaterial "
                         f"({type(exc).__name__}: {exc})") from None
    missing = [k for k in missing if not k.startswith("encoder.")]
    if missing or unexpected:
        raise InputError(f"{path}: {prim.GetPath()}: tensors missing {missing} or unexpected {unexpected} "
                         f"in {manifest_file}")
    model.surface = read_surface_files(manifest_file.parent)  # emission and opacity beside the latents, if any
    model.usd_info = {"layer": str(path), "material": str(prim.GetPath()),
                      "source_hash": prim.GetAttribute("neural:sourceHash").Get(),
                      "latent_textures": [str(t) for t in textures], "weights": str(weights_file),
                      "architecture": arch, "notes": manifest.get("notes", [])}
    return model.to(device).train(False)
