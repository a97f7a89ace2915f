"""The library entry point for pipelines: :func:`convert` a USD stage (open or on disk) or a file.

A DCC's Python node (Houdini, Maya, Omniverse) holds its scene as an open ``Usd.Stage``,
often with unsaved edits in session or anonymous layers; :func:`convert` bakes what that
stage composes, exactly as ``mtlx2neural ASSET`` bakes a file
(:func:`mtlx2neural.pipeline.convert.convert_asset`), and returns the neural layer.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from pxr import Sdf

from mtlx2neural.material_record import MaterialRecord
from mtlx2neural.pipeline.convert import convert_asset
from mtlx2neural.pipeline.options import ConvertOptions


@dataclass
class ConversionResult:
    """What :func:`convert` wrote."""

    layer: Sdf.Layer
    """The neural layer, opened from the written file (reloaded if this process had it open): add it
    to a stage (as a sublayer, or open it: it sublayers the input) to get the neural materials."""
    layer_path: Path
    """The neural layer's file (absolute)."""
    folder: Path
    """The output folder: per-material training files and exports, and the stage snapshot
    (``stage-snapshot.usda``) when the input had unsaved or in-memory edits."""
    summaries: list[MaterialRecord]
    """One :class:`~mtlx2neural.material_record.MaterialRecord` per converted material (``material``: the
    prim path; ``source``: the file to load its reference from; ``flip_mean``, ``cached``, ``usd``...),
    as stored in its folder's ``summary.json``."""
    skipped: list[dict]
    """The scene's materials left out (``{"material", "reason"}``, e.g. not bound to renderable
    geometry); empty when ``options.material`` named one."""
    failed: list[dict] = field(default_factory=list)
    """The selected materials that could not be converted (``{"material", "node", "reason"}``: an
    unsupported node, a bad value, a missing texture): the others were; these keep their original
    network only, and the layer's record lists them (``skippedMaterials``). Empty with
    ``options.strict``, which raises instead."""


def _open_layer(path: Path) -> Sdf.Layer:
    """The layer at ``path`` as it is on disk: the registry's copy reloaded when there is one."""
    layer = Sdf.Layer.Find(str(path))
    if layer is not None:
        layer.Reload(True)
        return layer
    layer = Sdf.Layer.FindOrOpen(str(path))
    if layer is None:
        raise OSError(f"{path}: cannot open the neural layer just written")
    return layer


def convert(stage_or_path, options: ConvertOptions | None = None) -> ConversionResult:
    """Bake every material the scene's renderable geometry binds (or only ``options.material``) into
    neural materials, and write the neural USD layer that offers them beside the originals.

    ``stage_or_path``: an open ``pxr.Usd.Stage`` (in memory or from a file), or the path of a USD
    (``.usda``/``.usdc``/``.usd``/``.usdz``) or ``.mtlx`` file. A stage is read as composed: its
    session-layer and unsaved edits are what gets baked, and it is never changed. When it
    equals its files (a file root layer, nothing unsaved), the run is that of the file; else
    the composed stage is flattened (asset paths made absolute) into
    ``<folder>/stage-snapshot.usda``, which the neural layer sublayers, with a warning when
    the root layer is a file. An in-memory root layer needs ``options.out``.

    ``options``: :class:`~mtlx2neural.pipeline.options.ConvertOptions` (None: its defaults, the
    ``fast`` preset on ``auto`` device; ``out`` defaults to ``<stem>_neural`` beside the file).
    Settings, device and every output path are checked before training; nothing is written
    outside the output folder and the layer. Raises :class:`~mtlx2neural.errors.InputError`
    (a bad input or option, with what to do; also when no selected material can be converted),
    ``OSError`` when writing fails (the previous export stays). A material that cannot be converted
    while others can is left out and listed in ``failed`` (``options.strict``: InputError instead).
    """
    if not (isinstance(stage_or_path, (str, os.PathLike)) or hasattr(stage_or_path, "GetRootLayer")):
        raise TypeError(f"convert() takes a Usd.Stage or a path to a USD or .mtlx file, not "
                        f"{type(stage_or_path).__name__}")
    if options is not None and not isinstance(options, ConvertOptions):
        raise TypeError(f"convert() takes its settings as a ConvertOptions (mtlx2neural.ConvertOptions), not "
                        f"{type(options).__name__}")
    summaries = convert_asset(stage_or_path, options if options is not None else ConvertOptions())
    path = Path(summaries.layer)
    return ConversionResult(layer=_open_layer(path), layer_path=path, folder=Path(summaries.folder),
                            summaries=list(summaries), skipped=list(summaries.skipped),
                            failed=list(getattr(summaries, "failed", [])))
