"""Every file an input asset reads: the set a conversion must never write to.

For a USD stage: the root layer and every layer and asset it reaches through
sublayers, references, payloads and asset-valued attributes (USD's own
``UsdUtils.ComputeAllDependencies``; unresolved paths are included as written,
made absolute, since a later run could create them). For every MaterialX
document a selected material comes from: the document's own file, the files it
``xi:include``s, and every ``filename`` input (textures), resolved as the
compiler resolves them. Paths are absolute and normalised (symbolic links
resolved), so two spellings of one file compare equal.

An open ``Usd.Stage`` counts like its files: its root layer's file (none for an
in-memory root) and the dependencies of its root and session layers, anonymous or
not (``ComputeAllDependencies`` walks their file sublayers, references, payloads and
assets; an anonymous layer itself has no file to protect).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

from mtlx2neural.imaging.resolve import on_disk

log = logging.getLogger(__name__)

USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")


def canonical(path) -> Path:
    """``path`` absolute, with symbolic links and ``..`` resolved (as far as it exists)."""
    return Path(os.path.realpath(os.path.abspath(os.fspath(path))))


def _is_anonymous(identifier: str) -> bool:
    return identifier.startswith("anon:")  # Sdf's prefix for anonymous layer identifiers


def _usd_dependencies(asset) -> set[Path]:
    """Dependencies of the USD layer ``asset`` (a file path, or an anonymous layer's identifier)."""
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import UsdUtils

    found: set[Path] = set()
    try:
        layers, assets, unresolved = UsdUtils.ComputeAllDependencies(str(asset))
    except Exception as exc:  # noqa: BLE001 - USD raises Tf errors for broken layers; loading reports them
        log.debug("%s: cannot compute its dependencies (%s)", asset, exc)
        return found
    for layer in layers:
        if layer.realPath:
            found.add(canonical(layer.realPath))
    for p in list(assets) + list(unresolved):
        if p and "<UDIM>" not in p:
            found.add(canonical(p))
    return found


def _mtlx_dependencies(document) -> set[Path]:
    """The document's files (``xi:include`` included) and its ``filename`` inputs."""
    found: set[Path] = set()
    for uri in [document.getSourceUri(), *document.getReferencedSourceUris()]:
        if uri and not _is_anonymous(uri):
            found.add(canonical(uri))
    for elem in document.traverseTree():
        if elem.getCategory() == "input" and elem.getAttribute("type") == "filename":
            value = elem.getResolvedValueString()
            if value and "<UDIM>" not in value:
                base = elem.getActiveSourceUri()
                base = "" if _is_anonymous(base) else base
                path = value if os.path.isabs(value) or not base else os.path.join(os.path.dirname(base), value)
                found.add(canonical(on_disk(path)))  # a texture named with another case: the file read
    return found


def _stage_dependencies(stage) -> set[Path]:
    root = stage.GetRootLayer()
    found = {canonical(root.realPath)} if not root.anonymous and root.realPath else set()
    for layer in (root, stage.GetSessionLayer()):
        found |= _usd_dependencies(layer.identifier)
    return found


def _mtlx_file_dependencies(path: Path) -> set[Path]:
    """The files the ``.mtlx`` file ``path`` reads (:func:`_mtlx_dependencies` of its document); an
    unreadable document reads nothing more here (loading it reports why)."""
    # Local: mtlx_file imports MaterialX and the standard libraries, needed only for a .mtlx asset.
    from mtlx2neural.errors import InputError
    from mtlx2neural.scene.mtlx_file import read_document

    try:
        return _mtlx_dependencies(read_document(path, validate=False))
    except InputError:
        return set()


def input_files(asset, sources=()) -> set[Path]:
    """Every file the asset ``asset`` (a path, or an open ``Usd.Stage``) and the material
    ``sources`` (:class:`MaterialSource`) read."""
    if hasattr(asset, "GetRootLayer"):  # a Usd.Stage (duck-typed: this module imports pxr lazily)
        found = _stage_dependencies(asset)
    else:
        asset = canonical(asset)
        found = {asset}
        if asset.suffix.lower() in USD_SUFFIXES:
            found |= _usd_dependencies(asset)
        elif asset.suffix.lower() == ".mtlx" and asset.is_file():  # its includes and textures, as USD's
            found |= _mtlx_file_dependencies(asset)
    for src in sources:
        if src.source_file and not _is_anonymous(src.source_file):
            found.add(canonical(src.source_file))
        if src.document is not None:  # None: a measured BRDF, whose table is its source_file
            found |= _mtlx_dependencies(src.document)
    return found
