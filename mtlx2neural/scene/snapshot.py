"""A snapshot of an open USD stage: its composed scene flattened into one layer file.

A stage that exists only in memory (an anonymous root layer), or whose layers hold
edits not saved to disk (session-layer opinions, a dirty file layer), has no file a
neural layer could sublayer and a later ``report`` or ``render`` could read the
reference material from. A conversion then writes :func:`flatten` of the stage into
its output folder (:func:`write_snapshot`) and treats that file as the input.

:func:`flatten` is ``UsdStage::Flatten`` of :func:`~.usd_stage.stage_view` (every
payload loaded), with asset paths anchored: Flatten makes a relative asset path
absolute only when it resolves; any other relative path (a missing file, a
search-path style path, a path authored in an anonymous layer, which has no folder)
is replaced by the absolute path the material converter uses for it
(:func:`~.usd_values.resolve_asset`: USD's resolved path, else anchored to the layer
that authored it, the current directory for an anonymous layer). So a material read
back from the snapshot is the document that was converted, with the same source hash.
Composition arcs are flattened away; a reference to a ``.mtlx`` file (which usd-core
cannot compose) is therefore not in the snapshot, and such materials keep their
``.mtlx`` file as their source.
"""

from __future__ import annotations

import os
from pathlib import Path

from pxr import Sdf, Usd

from mtlx2neural.atomic import atomic_path
from mtlx2neural.scene.usd_stage import stage_view
from mtlx2neural.scene.usd_values import resolve_asset


def unsaved_layers(stage: Usd.Stage) -> list[str]:
    """The layers ``stage`` uses whose content is not (all) on disk: non-empty anonymous layers
    (the session layer with edits, an in-memory root or sublayer) by identifier, and file
    layers with unsaved edits (``dirty``) by path. Empty for a stage that equals its files."""
    out = []
    for layer in stage.GetUsedLayers():
        if layer.anonymous:
            if not layer.empty:
                out.append(layer.identifier)
        elif layer.dirty:
            out.append(layer.realPath or layer.identifier)
    return sorted(out)


def _anchored(attr: Usd.Attribute, value):
    """``value`` (an ``Sdf.AssetPath`` or an array of them, as composed on ``attr``) with every
    relative path replaced by the absolute path the material converter uses."""
    if isinstance(value, Sdf.AssetPath):
        if not value.path or os.path.isabs(value.path):
            return value
        return Sdf.AssetPath(resolve_asset(attr, value))
    if value is None:
        return None
    return Sdf.AssetPathArray([_anchored(attr, v) for v in value])


def _anchor_asset_paths(view: Usd.Stage, flat: Sdf.Layer) -> None:
    asset_types = (Sdf.ValueTypeNames.Asset, Sdf.ValueTypeNames.AssetArray)
    paths: list[Sdf.Path] = []
    flat.Traverse(Sdf.Path.absoluteRootPath, lambda p: paths.append(p) if p.IsPropertyPath() else None)
    for path in paths:
        spec = flat.GetAttributeAtPath(path)
        if spec is None or spec.typeName not in asset_types:
            continue
        attr = view.GetAttributeAtPath(path)
        if not attr:  # a prototype's copy under /Flattened_Prototype_N: Flatten's value stays
            continue
        if spec.HasDefaultValue():
            spec.default = _anchored(attr, attr.Get(Usd.TimeCode.Default()))
        for t in flat.ListTimeSamplesForPath(path):
            flat.SetTimeSample(path, t, _anchored(attr, attr.Get(t)))


def flatten(stage: Usd.Stage) -> Sdf.Layer:
    """The composed ``stage`` (its unsaved and session-layer edits included, every payload
    loaded) as one anonymous layer, asset paths anchored (module docstring). ``stage`` is
    not changed."""
    view = stage_view(stage)
    flat = view.Flatten(addSourceFileComment=False)
    _anchor_asset_paths(view, flat)
    return flat


def write_snapshot(layer: Sdf.Layer, path) -> Path:
    """Write ``layer`` (from :func:`flatten`) to ``path`` atomically (a temporary sibling, then a
    rename): a reader never sees half a snapshot. Returns ``path``; ``OSError`` when it cannot."""
    path = Path(path)
    with atomic_path(path) as tmp:
        if not layer.Export(str(tmp)):
            raise OSError(f"{path}: cannot write the snapshot of the USD stage")
    return path
