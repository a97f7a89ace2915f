"""The MaterialX standard data libraries, loaded once, and document validation.

Documents handed to later stages hold only user content; the libraries are
attached (never copied) to scratch copies when something needs to look up a
nodedef or validate.
"""

from __future__ import annotations

import functools
import os

import MaterialX as mx

from mtlx2neural.errors import InputError


def library_dir() -> str:
    """Absolute path of the ``libraries`` folder shipped with the MaterialX package."""
    return os.path.realpath(os.path.join(os.path.dirname(mx.__file__), "libraries"))


@functools.lru_cache(maxsize=1)
def standard_library() -> "mx.Document":
    """The MaterialX standard data libraries (stdlib, pbrlib, bxdf, ...), loaded once.

    Callers must treat the returned document as read-only.
    """
    lib = mx.createDocument()
    search = mx.FileSearchPath(os.path.dirname(library_dir()))
    mx.loadLibraries(["libraries"], search, lib)
    if not lib.getNodeDefs():  # pragma: no cover - broken MaterialX install
        raise RuntimeError(f"no MaterialX nodedefs found under {library_dir()}")
    return lib


def nodedef(name: str) -> "mx.NodeDef | None":
    """The standard-library nodedef called ``name`` (e.g. ``ND_image_color3``), or None."""
    return standard_library().getNodeDef(name)


def output_types(nd: "mx.NodeDef") -> dict[str, str]:
    """Map each output name of ``nd`` (including inherited ones) to its MaterialX type."""
    return {o.getName(): o.getType() for o in nd.getActiveOutputs()}


def node_type(nd: "mx.NodeDef") -> str:
    """The ``type`` attribute a node instance of ``nd`` carries (``multioutput`` for several outputs)."""
    outs = nd.getActiveOutputs()
    if len(outs) == 1:
        return outs[0].getType()
    return "multioutput"


def is_library_element(elem: "mx.Element") -> bool:
    """True when ``elem`` was read from a file inside MaterialX's own library folder."""
    uri = elem.getSourceUri()
    if not uri:
        return False
    path = os.path.realpath(uri)
    return path.startswith(library_dir() + os.sep)


TEXT_TYPES = {"string", "filename", "geomname", "token"}
"""Value types every string parses as."""


def unparsed_values(doc: "mx.Document") -> list[str]:
    """One line per value of ``doc`` that does not parse as its type (``<input type="float"
    value="abc">``), naming the node (its path), the input, the type and the value."""
    lines = []
    for elem in doc.traverseTree():
        if not isinstance(elem, mx.ValueElement) or elem.getType() in TEXT_TYPES:
            continue
        text = elem.getValueString() if elem.hasValueString() else ""
        if not text.strip():
            continue
        try:
            value = elem.getValue()
        except Exception:  # noqa: BLE001 - MaterialX raises plain exceptions for some types
            value = None
        if value is None:
            owner = elem.getParent()
            lines.append(f"Node {owner.getNamePath()!r} ({owner.getCategory()}): {elem.getCategory()} "
                         f"{elem.getName()!r} has value {text!r}, which does not parse as a {elem.getType()}")
    return lines


def validate(doc: "mx.Document", what: str) -> None:
    """Validate ``doc`` against the standard libraries without modifying it.

    ``what`` names the file (and material) for the message. Raises InputError
    listing MaterialX's own complaints when the document is invalid.
    """
    scratch = mx.createDocument()
    scratch.copyContentFrom(doc)
    # Attaching the libraries as the data library is equivalent to importing
    # them for lookups and validation, ~10x cheaper, and user elements can't
    # shadow library elements of the same name.
    scratch.setDataLibrary(standard_library())
    ok, message = scratch.validate()
    unparsed = unparsed_values(doc)
    if unparsed:
        ok, message = False, "".join(f"{line}\n" for line in unparsed) + message
    # validate() accepts nodes that match no nodedef; nothing downstream can use them.
    for elem in doc.traverseTree():
        if not isinstance(elem, mx.Node):
            continue
        node = scratch.getDescendant(elem.getNamePath())
        if node is not None and node.getNodeDef() is None:
            ok = False
            message += (
                f"Node {elem.getNamePath()!r} (category {elem.getCategory()!r}, type {elem.getType()!r}) "
                "matches no nodedef in the document or the standard libraries\n"
            )
    if not ok:
        details = "\n".join("  " + line for line in message.strip().splitlines()[:20])
        raise InputError(
            f"{what}: the MaterialX document is not valid:\n{details}\n"
            "Fix the listed elements (check node categories, types and connections "
            "against the MaterialX specification) and try again."
        )
