"""Materials that a USD stage brings in by referencing a ``.mtlx`` file.

usd-core from PyPI has no usdMtlx file-format plugin, so a reference such as
``references = @./plastic.mtlx@</MaterialX>`` does not compose: the prims it
would create are simply absent. This module finds such arcs in the authored
prim specs and works out where each material of the ``.mtlx`` file would have
appeared, using usdMtlx's layout: the file's default prim is ``/MaterialX``
and each ``surfacematerial`` node ``M`` becomes ``/MaterialX/Materials/M``.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass

from pxr import Sdf, Usd, UsdShade

from mtlx2neural.scene import mtlx_file

log = logging.getLogger(__name__)

MTLX_ROOT = Sdf.Path("/MaterialX")
MTLX_MATERIALS = MTLX_ROOT.AppendChild("Materials")


@dataclass(frozen=True)
class MtlxReference:
    """One material reached through a ``.mtlx`` reference or payload."""

    stage_path: str  # where the Material would be on the composed stage
    mtlx_path: str  # absolute path of the referenced .mtlx file
    material: str  # surfacematerial node name inside that file
    referencing_layer: str  # the layer that authored the arc, for messages


def _mtlx_arcs(prim: Usd.Prim):
    """Yield ``(absolute .mtlx path, target prim path, layer)`` for each .mtlx arc on ``prim``."""
    for spec in prim.GetPrimStack():
        items = list(spec.referenceList.GetAddedOrExplicitItems())
        items += list(spec.payloadList.GetAddedOrExplicitItems())
        for item in items:
            asset = item.assetPath
            if not asset or not asset.lower().endswith(".mtlx"):
                continue
            path = spec.layer.ComputeAbsolutePath(asset) if not spec.layer.anonymous else asset
            if not os.path.isabs(path) and spec.layer.realPath:
                path = os.path.join(os.path.dirname(spec.layer.realPath), asset)
            target = item.primPath if not item.primPath.isEmpty else MTLX_ROOT
            yield os.path.normpath(os.path.abspath(path)), target, spec.layer


def find_mtlx_references(stage: Usd.Stage) -> list[MtlxReference]:
    """All materials that ``.mtlx`` references/payloads on ``stage`` would create.

    Reads each referenced file (with validation); a referenced file that is
    missing or invalid raises InputError. Arcs whose target names no material
    of the file (for example a reference to a nodegraph) are logged and ignored.
    """
    found: dict[str, MtlxReference] = {}
    for prim in stage.Traverse(Usd.TraverseInstanceProxies(Usd.PrimAllPrimsPredicate)):
        if not prim.IsActive() or not (prim.HasAuthoredReferences() or prim.HasAuthoredPayloads()):
            continue
        for mtlx_path, target, layer in _mtlx_arcs(prim):
            doc = mtlx_file.read_document(mtlx_path)
            matched = False
            for name in mtlx_file.material_names(doc):
                virtual = MTLX_MATERIALS.AppendChild(name)
                if not virtual.HasPrefix(target):
                    continue
                stage_path = str(virtual.ReplacePrefix(target, prim.GetPath()))
                found.setdefault(
                    stage_path,
                    MtlxReference(stage_path, mtlx_path, name, layer.realPath or layer.identifier),
                )
                matched = True
            if not matched:
                log.warning(
                    "%s: <%s> references %s<%s>, which names no surfacematerial of that file; ignored.",
                    layer.realPath or layer.identifier,
                    prim.GetPath(),
                    mtlx_path,
                    target,
                )
    return list(found.values())


def add_placeholders(stage: Usd.Stage, refs: list[MtlxReference]) -> None:
    """Define a Material prim for each reference in the stage's (in-memory) session layer.

    This lets UsdShade's binding resolution (direct, collection, inherited)
    find the materials exactly as it would with usdMtlx. Nothing is saved.
    """
    session = stage.GetSessionLayer()
    with Usd.EditContext(stage, session):
        for ref in refs:
            prim = stage.GetPrimAtPath(ref.stage_path)
            if prim and prim.IsA(UsdShade.Material):
                continue
            # Missing ancestors are authored as typeless defs, as the reference would have.
            UsdShade.Material.Define(stage, Sdf.Path(ref.stage_path))
