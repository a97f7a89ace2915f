"""Reading ``.mtlx`` files: XIncludes, absolute texture paths, validation.

Every ``surfacematerial`` node in the file is a material. The document handed
on holds only the user's content (the standard libraries are never imported
into it), with every ``filename`` value made absolute so that it no longer
depends on the file's location or on ``fileprefix`` attributes.
"""

from __future__ import annotations

import functools
import os
import re

import MaterialX as mx

from mtlx2neural.errors import InputError, missing_reason, unreadable_reason
from mtlx2neural.scene import mxlib

MATERIAL_CATEGORY = "surfacematerial"


def _abspath(path) -> str:
    return os.path.abspath(os.fspath(path))


@functools.lru_cache(maxsize=64)
def _read_cached(path: str, mtime_ns: int, search_env: str, validate: bool = True) -> "mx.Document":
    return _read_uncached(path, validate)


def read_document(path, validate: bool = True) -> "mx.Document":
    """Read, clean and validate the ``.mtlx`` file at ``path``.

    Returns a new document (a private copy; callers may modify it) whose
    ``filename`` inputs are absolute paths (``<UDIM>``/``<UVTILE>`` tokens kept)
    and that contains no standard-library elements. Raises InputError when the
    file is missing or unreadable (a permission problem is named as such,
    for the file and for anything it XIncludes), is not well-formed XML, has an
    unresolvable XInclude, or (``validate``) fails ``validate()`` against the standard libraries.
    """
    path = _abspath(path)
    if not os.path.isfile(path):
        raise InputError(f"{path}: the MaterialX file {missing_reason(path, 'was not found')}. Check the path.")
    check_readable(path)  # every time: permissions may change without the mtime
    cached = _read_cached(path, os.stat(path).st_mtime_ns, os.environ.get("MATERIALX_SEARCH_PATH", ""), validate)
    doc = mx.createDocument()
    doc.copyContentFrom(cached)
    for elem in doc.traverseTree():
        # XIncluded content would otherwise be written back out as xi:include.
        elem.setSourceUri("")
    doc.setSourceUri(path)
    return doc


def _read_uncached(path: str, validate: bool = True) -> "mx.Document":
    doc = mx.createDocument()
    search = mx.FileSearchPath(os.path.dirname(path))
    search.append(mx.FilePath(os.path.dirname(mxlib.library_dir())))
    try:
        mx.readFromXmlFile(doc, path, search)
    except mx.ExceptionFileMissing as exc:
        unreadable = _unreadable_include(str(exc), os.path.dirname(path))
        if unreadable:
            check_readable(unreadable, f"It is included (xi:include) by {path}. ")
        raise InputError(
            f"{path}: a file it includes (xi:include) could not be found: {exc}. "
            "Fix the include path or restore the missing file."
        ) from exc
    except mx.Exception as exc:
        raise InputError(
            f"{path}: not a readable MaterialX document: {exc}. Check that the file is well-formed MaterialX XML."
        ) from exc
    except Exception as exc:  # MaterialX raises plain exceptions for some parse errors
        raise InputError(
            f"{path}: not a readable MaterialX document: {exc}. Check that the file is well-formed MaterialX XML."
        ) from exc
    _drop_library_elements(doc)
    wrap_shader_outputs(doc)
    absolutize_filenames(doc, os.path.dirname(path), search)
    if validate:
        mxlib.validate(doc, path)
    return doc


def check_readable(path: str, context: str = "") -> None:
    """Raise InputError when the existing file ``path`` cannot be opened for reading.

    ``context`` (a sentence, e.g. who includes the file) goes into the message. A
    permission problem is reported as such, not as a missing or malformed file.
    """
    reason = unreadable_reason(path)
    if reason is not None:
        raise InputError(f"cannot read {path}: {reason}. {context}Give the current user read access to the file "
                         f"(and search access to its folders) and try again.")


def _unreadable_include(message: str, base_dir: str) -> str | None:
    """The file named by MaterialX's "Failed to open file for reading: X" when X exists but cannot be read."""
    match = re.search(r"for reading:\s*(.+?)\s*$", message)
    if not match:
        return None
    name = match.group(1)
    candidate = name if os.path.isabs(name) else os.path.join(base_dir, name)
    if not os.path.isfile(candidate) or unreadable_reason(candidate) is None:
        return None
    return os.path.normpath(candidate)


def _drop_library_elements(doc: "mx.Document") -> None:
    """Remove top-level elements that an XInclude pulled in from MaterialX's own libraries."""
    for child in list(doc.getChildren()):
        if mxlib.is_library_element(child):
            doc.removeChild(child.getName())


def wrap_shader_outputs(doc: "mx.Document") -> list[str]:
    """Give every free-standing surface shader a material, as MaterialX's renderers do.

    Test and library files often hold nodegraphs whose ``surfaceshader`` outputs
    no ``surfacematerial`` uses (MaterialX's own test suite renders each such
    output). Each gets a ``surfacematerial`` named ``<nodegraph>_<output>``.
    Returns the names added.
    """
    used = set()
    for mat in doc.getNodes():
        if mat.getCategory() == MATERIAL_CATEGORY:
            inp = mat.getInput("surfaceshader")
            if inp is not None and inp.getNodeGraphString():
                used.add((inp.getNodeGraphString(), inp.getOutputString()))
    added = []
    for ng in doc.getNodeGraphs():
        if ng.hasNodeDefString():
            continue  # a definition, not a network
        outs = [o for o in ng.getOutputs() if o.getType() == "surfaceshader"]
        for out in outs:
            if (ng.getName(), out.getName()) in used or (ng.getName(), "") in used:
                continue
            name = doc.createValidChildName(f"{ng.getName()}_{out.getName()}")
            mat = doc.addNode(MATERIAL_CATEGORY, name, "material")
            shader_in = mat.addInput("surfaceshader", "surfaceshader")
            shader_in.setNodeGraphString(ng.getName())
            shader_in.setOutputString(out.getName())
            added.append(name)
    return added


def absolutize_filenames(doc: "mx.Document", default_dir: str, search: "mx.FileSearchPath | None" = None) -> None:
    """Make every ``filename``-typed value in ``doc`` an absolute, normalised path.

    ``fileprefix`` attributes on ancestors are applied first (they are then
    removed, since the values no longer need them). Relative paths are taken
    relative to the directory of the file that defined the element (its
    source URI, which differs from ``default_dir`` for XIncluded content;
    a relative source URI is looked up on ``search``, the path the file was
    read with).
    Empty values stay empty; ``<UDIM>`` and ``<UVTILE>`` tokens are kept.
    A relative path that does not exist beside its document is looked up on
    ``MATERIALX_SEARCH_PATH``. One leniency: when the prefixed path does not exist but the value alone
    does (files written for usdMtlx, which ignored ``fileprefix``, repeat the
    prefix in the value), the existing file wins.
    """
    resolved: list[tuple["mx.ValueElement", str]] = []
    for elem in doc.traverseTree():
        if not isinstance(elem, mx.ValueElement) or elem.getType() != "filename":
            continue
        if not elem.hasValueString() or not elem.getValueString():
            continue
        base = _source_dir(elem.getActiveSourceUri(), default_dir, search)
        value = os.path.normpath(os.path.join(base, elem.getResolvedValueString()))
        raw = os.path.normpath(os.path.join(base, elem.getValueString()))
        if raw != value and _missing(value) and not _missing(raw):
            # Files written for usdMtlx (which ignored fileprefix) repeat the
            # prefix in the value; keep the path that names an existing file.
            value = raw
        if _missing(value):
            value = _on_search_path(elem.getResolvedValueString()) or value
        resolved.append((elem, value))
    for elem, value in resolved:
        elem.setValueString(value)
    for elem in [doc, *doc.traverseTree()]:
        if elem.hasFilePrefix():
            elem.removeAttribute(mx.Element.FILE_PREFIX_ATTRIBUTE)


def _on_search_path(relative: str) -> str | None:
    """``relative`` found under a folder of ``MATERIALX_SEARCH_PATH`` (MaterialX's own
    environment search path, as its viewers and test runners resolve textures), or None."""
    if os.path.isabs(relative):
        return None
    found = mx.getEnvironmentPath().find(mx.FilePath(relative)).asString()
    return os.path.normpath(found) if os.path.isabs(found) and not _missing(found) else None


def _missing(path: str) -> bool:
    if "<UDIM>" in path or "<UVTILE>" in path:
        return False  # patterns are checked by the texture stage
    return not os.path.exists(path)


def _source_dir(uri: str, default_dir: str, search: "mx.FileSearchPath | None") -> str:
    if not uri:
        return default_dir
    if not os.path.isabs(uri):
        found = search.find(mx.FilePath(uri)).asString() if search is not None else ""
        uri = found if found and os.path.isabs(found) else os.path.join(default_dir, uri)
    return os.path.dirname(os.path.normpath(uri))


def material_names(doc: "mx.Document") -> list[str]:
    """Names of the ``surfacematerial`` nodes at the top level of ``doc``, in document order."""
    return [n.getName() for n in doc.getNodes() if n.getCategory() == MATERIAL_CATEGORY]


def material_document(doc: "mx.Document", name: str) -> "mx.Document":
    """A copy of ``doc`` holding, of its top-level nodes and node graphs, only those the material
    ``name`` reaches upstream (node graphs that implement a nodedef, and every other element such
    as nodedefs and typedefs, stay): what one material of a multi-material file is made of."""
    own = mx.createDocument()
    own.copyContentFrom(doc)
    own.setSourceUri(doc.getSourceUri())
    keep, stack = set(), [name]
    while stack:
        elem = own.getChild(stack.pop())
        if elem is None or elem.getName() in keep:
            continue
        keep.add(elem.getName())
        for sub in elem.traverseTree():
            if sub.getCategory() in ("input", "output"):
                stack += [v for v in (sub.getAttribute("nodename"), sub.getAttribute("nodegraph")) if v]
    for elem in list(own.getChildren()):
        graph = isinstance(elem, mx.NodeGraph) and not elem.getAttribute("nodedef")
        if (isinstance(elem, mx.Node) or graph) and elem.getName() not in keep:
            own.removeChild(elem.getName())
    return own


def material_errors(doc: "mx.Document", path: str) -> dict[str, InputError | None]:
    """Each material of ``doc`` (read without validation) -> the :class:`InputError` its own part of
    the document (:func:`material_document`) fails validation with, or None when that part is valid."""
    errors = {}
    for name in material_names(doc):
        try:
            mxlib.validate(material_document(doc, name), f"{path} (material {name})")
            errors[name] = None
        except InputError as exc:
            errors[name] = exc
    return errors
