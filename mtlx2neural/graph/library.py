"""Access to MaterialX's own standard data libraries (stdlib, pbrlib, bxdf, ...).

The libraries ship inside the ``MaterialX`` Python package. They are loaded once
per process and imported into a scratch copy of each user document, so that
``node.getNodeDef()`` and nodegraph implementations resolve exactly as they do in
MaterialX's own shader generators.
"""

from __future__ import annotations

import functools
import os

import MaterialX as mx


def library_root() -> str:
    """Folder holding MaterialX's ``libraries/`` tree (stdlib, pbrlib, bxdf, ...)."""
    return os.path.join(os.path.dirname(mx.__file__), "libraries")


@functools.lru_cache(maxsize=1)
def standard_library() -> mx.Document:
    """The standard data libraries as one document (loaded once, never modified)."""
    lib = mx.createDocument()
    search = mx.FileSearchPath(os.path.dirname(library_root()))
    mx.loadLibraries(["libraries"], search, lib)
    return lib


def with_libraries(document: mx.Document) -> mx.Document:
    """A new document holding a copy of ``document`` plus the standard libraries.

    The input document is left untouched.
    """
    merged = mx.createDocument()
    merged.copyContentFrom(document)
    merged.setSourceUri(document.getSourceUri())
    merged.importLibrary(standard_library())
    return merged


def nodegraph_implementation(document: mx.Document, nodedef: mx.NodeDef):
    """The NodeGraph that implements ``nodedef`` in ``document``, or None."""
    impl = nodedef.getImplementation()
    if impl is not None and impl.isA(mx.NodeGraph):
        return impl
    for candidate in document.getMatchingImplementations(nodedef.getName()):
        if candidate.isA(mx.NodeGraph):
            return candidate
    return None
