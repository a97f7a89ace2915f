"""USD stages: open safely, list every Material, decide which are needed, convert them.

Materials come from two places: UsdShade networks on the stage (converted by
``usd_to_mtlx``) and ``.mtlx`` files the stage references, which usd-core
cannot compose (read by ``mtlx_file``; see ``mtlx_refs``). A Material is
selected when renderable geometry binds it (see ``binding``).

The stage is opened read-only in spirit: the only edits go to its in-memory
session layer (placeholder Material prims for ``.mtlx`` references) and are
never saved.

An already open ``Usd.Stage`` (a DCC's scene, possibly in memory) is read through
:func:`stage_view`: a private stage over the very same root and session layers
(their unsaved edits included), so the caller's stage is never edited and the
materials are selected by the same code as for a file.
"""

from __future__ import annotations

import logging
import os
import re

from pxr import Pcp, Sdf, Tf, Usd, UsdShade

from mtlx2neural.errors import InputError, missing_reason
from mtlx2neural.scene import binding, mtlx_file, mxlib
from mtlx2neural.scene.materials import Candidate, MaterialSource
from mtlx2neural.scene.mtlx_refs import (
    MtlxReference,
    add_placeholders,
    find_mtlx_references,
)
from mtlx2neural.scene.usd_to_mtlx import convert_material, defining_file

log = logging.getLogger(__name__)

USD_EXTENSIONS = (".usd", ".usda", ".usdc", ".usdz")


def open_stage(path: str) -> Usd.Stage:
    """Open the USD file at ``path``; InputError when it is missing, unreadable or cannot be parsed."""
    if not os.path.isfile(path):
        raise InputError(f"{path}: the USD file {missing_reason(path, 'was not found')}. Check the path.")
    mtlx_file.check_readable(path)  # else USD reports only "failed to open layer"
    try:
        stage = Usd.Stage.Open(path, Usd.Stage.LoadAll)
    except Tf.ErrorException as exc:
        raise InputError(f"{path}: not a readable USD file: {_tf_message(exc)}. Fix the file and try again.") from exc
    if stage is None:
        raise InputError(f"{path}: not a readable USD file. Fix the file and try again.")
    _log_composition_errors(stage, path)
    return stage


def _log_composition_errors(stage: Usd.Stage, name: str) -> None:
    for err in stage.GetCompositionErrors():
        if isinstance(err, Pcp.ErrorInvalidAssetPath) and ".mtlx" in str(err):
            continue  # handled by mtlx_refs
        log.warning("%s: composition error: %s", name, err)


def is_stage(asset) -> bool:
    """Whether ``asset`` is an open ``Usd.Stage`` (rather than a path)."""
    return isinstance(asset, Usd.Stage)


def stage_name(stage: Usd.Stage) -> str:
    """How messages name an open stage: its root layer's file, or ``in-memory stage <identifier>``."""
    root = stage.GetRootLayer()
    return root.realPath if not root.anonymous and root.realPath else f"in-memory stage {root.identifier}"


def stage_view(stage: Usd.Stage) -> Usd.Stage:
    """A private stage composing exactly what ``stage`` composes, with every payload loaded.

    It opens the same root layer object (so unsaved edits count) with a fresh anonymous
    session layer that sublayers ``stage``'s session layer (so session-layer edits and
    variant selections count too) and ``stage``'s path resolver context. Edits made to
    the view (the ``.mtlx`` placeholders) go to its own session layer: ``stage`` is not
    changed. Like a file input, everything is loaded (``Usd.Stage.LoadAll``), whatever
    ``stage`` has loaded, and no population mask applies.
    """
    if not stage or not stage.GetPseudoRoot():
        raise InputError("the USD stage given is not valid (expired or closed); pass an open Usd.Stage.")
    session = Sdf.Layer.CreateAnonymous("mtlx2neural-view.usda")
    session.subLayerPaths.append(stage.GetSessionLayer().identifier)
    view = Usd.Stage.Open(stage.GetRootLayer(), session, stage.GetPathResolverContext(), Usd.Stage.LoadAll)
    _log_composition_errors(view, stage_name(stage))
    return view


def _tf_message(exc: Exception) -> str:
    messages = re.findall(r" : '(.*?)'\s*$", str(exc), re.M | re.S)
    return "; ".join(m.strip() for m in messages) or str(exc).strip()


def candidates(path) -> list[Candidate]:
    """Every Material on the USD stage at ``path`` (a file path, or an open ``Usd.Stage``, read
    through :func:`stage_view`), each with its skip reason and a loader.

    Order: stage traversal order, then materials only reachable through bindings.
    """
    stage = stage_view(path) if is_stage(path) else open_stage(path)
    refs = {r.stage_path: r for r in find_mtlx_references(stage)}
    add_placeholders(stage, list(refs.values()))
    bindings = binding.collect_bindings(stage)

    paths: list[str] = []
    predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
    for prim in stage.Traverse(predicate):
        if prim.IsA(UsdShade.Material):
            paths.append(str(prim.GetPath()))
    seen = set(paths)
    for extra in [*refs, *bindings.uses]:
        if extra not in seen:
            paths.append(extra)
            seen.add(extra)

    out = []
    for mat_path in paths:
        ref = refs.get(mat_path)
        aliases = [mat_path.rsplit("/", 1)[-1]]
        if ref is not None:
            aliases.append(ref.material)
        use = bindings.uses.get(mat_path)
        bound = list(use.renderable) if use else []
        out.append(
            Candidate(
                key=mat_path,
                aliases=tuple(dict.fromkeys(aliases)),
                reason=binding.skip_reason(bindings, mat_path),
                load=_loader(stage, mat_path, ref, bound),
            )
        )
    return out


def _loader(stage: Usd.Stage, mat_path: str, ref: MtlxReference | None, bound: list[str]):
    def load() -> MaterialSource:
        src = _from_mtlx_reference(ref, bound) if ref is not None else _from_network(stage, mat_path, bound)
        root = stage.GetRootLayer()
        src.stage_file = None if root.anonymous or not root.realPath else os.path.abspath(root.realPath)
        return src

    return load


def _from_mtlx_reference(ref: MtlxReference, bound: list[str]) -> MaterialSource:
    doc = mtlx_file.read_document(ref.mtlx_path)
    return MaterialSource(
        name=ref.stage_path,
        document=doc,
        material=ref.material,
        source_file=ref.mtlx_path,
        bound_prims=bound,
    )


def _from_network(stage: Usd.Stage, mat_path: str, bound: list[str]) -> MaterialSource:
    prim = stage.GetPrimAtPath(mat_path)
    if not prim or not prim.IsA(UsdShade.Material):
        root = stage.GetRootLayer().realPath or stage.GetRootLayer().identifier
        raise InputError(
            f"{root}: <{mat_path}> is bound as a material but is not a Material prim. Fix the material:binding target."
        )
    source_file = defining_file(prim)
    if not Sdf.Layer.IsAnonymousLayerIdentifier(source_file):
        source_file = os.path.abspath(source_file)
    doc, node_name = convert_material(UsdShade.Material(prim), source_file)
    mxlib.validate(doc, f"{source_file}: <{mat_path}> (converted to MaterialX)")
    return MaterialSource(
        name=mat_path,
        document=doc,
        material=node_name,
        source_file=source_file,
        bound_prims=bound,
        network=True,
        preview_surface=_is_preview_surface(UsdShade.Material(prim)),
    )


def _is_preview_surface(material: UsdShade.Material) -> bool:
    """Whether ``material``'s universal surface output resolves to a ``UsdPreviewSurface`` shader that is
    also what its ``mtlx`` render context resolves to (:attr:`MaterialSource.preview_surface`)."""
    universal, mtlx = material.ComputeSurfaceSource()[0], material.ComputeSurfaceSource("mtlx")[0]
    return bool(universal) and universal.GetPath() == mtlx.GetPath() and universal.GetIdAttr().Get() == "UsdPreviewSurface"
