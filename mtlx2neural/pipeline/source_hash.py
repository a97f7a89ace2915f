"""The source hash that decides whether a material needs training again.

``source_hash`` is a sha256 over, in order:

- ``FORMAT_VERSION`` (the exported format; bumping it invalidates every cache) and
  ``TRAINING_VERSION`` (what a material trains to, for the same input and settings: bumped when a
  change of the tool changes the training targets or the stack, so that old checkpoints are not
  reused; it leaves exported assets loadable, which a ``FORMAT_VERSION`` bump would not);
- the material's name (prim path or MaterialX name) and surfacematerial node name;
- the material's MaterialX document as XML (``mx.writeToXmlString``). For a ``.mtlx``
  input this is the whole file's content, so editing another material of the same
  file retrains this one too (conservative: a nodegraph or nodedef it shares is
  never missed). For USD input it is the document built from that material's network;
- every file a ``filename`` input of the document names (UDIM sets expanded to their
  tiles): its path and the sha256 of its bytes (memoised per path, size and mtime);
  a file found only by ignoring case (:mod:`mtlx2neural.imaging.resolve`) hashes as the file
  read; a missing file hashes as "missing", and whether missing textures are allowed;
- the training settings (``dataclasses.asdict(TrainConfig)``) except those that do not
  change the result (``IGNORED_SETTINGS``), and the OCIO config in use (``$OCIO``).

``convert_asset`` stores the hash in ``summary.json``; a later run with the same hash
reuses the checkpoint instead of training (``--force`` retrains).

``content_hash`` is the name-free counterpart that finds materials of one scene that
would train to the same model (trained once, shared: :mod:`mtlx2neural.pipeline.plan`). It hashes
the *compiled* material rather than the document, so node names, prim paths and
``doc`` strings do not matter: every IR node in order (category, nodedef, outputs,
attributes, inputs as constants or references to earlier nodes; not its path), the
bytes of every file its image nodes read, then the same settings, OCIO config and
missing-texture flag as ``source_hash``. Two graphs that compile to the same operators
hash equal; a graph whose node order depends on names only misses a chance to share.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path

import MaterialX as mx

from mtlx2neural.errors import InputError
from mtlx2neural.formats import FORMAT_VERSION
from mtlx2neural.imaging.packages import local_file
from mtlx2neural.imaging.resolve import on_disk
from mtlx2neural.imaging.udim import discover_tiles, is_tiled_path
from mtlx2neural.material_record import MaterialRecord, read_record_or_none

IGNORED_SETTINGS = ("checkpoint_every", "compile", "probe_every")  # the same model either way
TRAINING_VERSION = 3
"""Version of the training targets (module docstring). History: 1, before versions were hashed; 2, the
LEAN tangent (:mod:`mtlx2neural.textures.parameter_stack` passes each anisotropic lobe's tangent to the
moments, so a material with a non-default tangent, e.g. a ``specular_rotation``, trains to other targets);
3, opacity kept beside the BRDF instead of scaling it, and emission kept (:mod:`mtlx2neural.graph.surface_terms`)."""
_file_digests: dict[tuple[str, int, int], str] = {}


def file_digest(path: str) -> str:
    """sha256 of the file's bytes, memoised by (path, size, mtime)."""
    st = os.stat(path)
    key = (path, st.st_size, st.st_mtime_ns)
    if key not in _file_digests:
        h = hashlib.sha256()
        with open(path, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
        _file_digests[key] = h.hexdigest()
    return _file_digests[key]


def referenced_files(document) -> list[str]:
    """Every file named by a ``filename`` input of ``document`` (UDIM patterns expanded), sorted."""

    files = set()
    for elem in document.traverseTree():
        if elem.getCategory() != "input" or elem.getAttribute("type") != "filename":
            continue
        value = elem.getValueString()
        if not value:
            continue
        if is_tiled_path(value):
            files.update(discover_tiles(value).values())
            files.add(value)  # the pattern itself: a set that gains or loses tiles changes the hash
        else:
            files.add(value)
    return sorted(files)


def settings_for_hash(cfg) -> dict:
    return {k: v for k, v in dataclasses.asdict(cfg).items() if k not in IGNORED_SETTINGS}


def _put_input(put, source) -> None:
    """Feed the material's own input (name, MaterialX document, referenced files' contents) to ``put``."""

    put("material", f"{source.name}\0{source.material}")
    if getattr(source, "measured", False):  # a MERL table: its bytes are the whole input
        put("measured", file_digest(source.source_file))
        return
    put("document", mx.writeToXmlString(source.document))
    for f in referenced_files(source.document):
        put("file", f)
        f = on_disk(f)  # the file read when the document's spelling differs only in case
        try:
            f = local_file(f)  # a member of a USDZ package: its bytes
        except InputError:
            pass  # unreadable: "missing" below, and compiling the material reports it
        put("digest", file_digest(f) if os.path.isfile(f) else "missing")


def input_hash(source) -> str:
    """Hex sha256 of the material's input alone (document and referenced files, no settings): the
    summary's ``input_hash``, which tells whether a material kept from an earlier run is stale."""
    h = hashlib.sha256()

    def put(tag: str, text: str) -> None:
        data = text.encode()
        h.update(f"{tag}:{len(data)}:".encode() + data)

    _put_input(put, source)
    return h.hexdigest()


def source_hash(source, cfg, allow_missing_textures: bool = False) -> str:
    """Hex sha256 of everything a trained material depends on (see the module docstring)."""
    h = hashlib.sha256()

    def put(tag: str, text: str) -> None:
        data = text.encode()
        h.update(f"{tag}:{len(data)}:".encode() + data)

    put("format", str(FORMAT_VERSION))
    put("training", str(TRAINING_VERSION))
    _put_input(put, source)
    put("allow_missing_textures", str(bool(allow_missing_textures)))
    put("settings", json.dumps(settings_for_hash(cfg), sort_keys=True, default=str))
    put("ocio", os.environ.get("OCIO", ""))
    return h.hexdigest()


def graph_text(compiled) -> str:
    """The compiled material's IR as name-free text, one line per node (see the module docstring)."""
    lines = []
    for node in compiled.graph.nodes:
        ins = []
        for key in sorted(node.inputs):
            v = node.inputs[key]
            ins.append(f"{key}=@{v.node}.{v.output}" if hasattr(v, "node")
                       else f"{key}={v.type}:{v.value!r}:{v.colorspace}")
        lines.append("|".join([node.category, node.nodedef, json.dumps(node.outputs, sort_keys=True),
                               json.dumps(node.attrs, sort_keys=True), *ins]))
    return "\n".join(lines)


def graph_files(compiled) -> list[str]:
    """Every file a ``filename`` constant of the compiled graph names (UDIM sets expanded), sorted."""

    files = set()
    for node in compiled.graph.nodes:
        for v in node.inputs.values():
            if getattr(v, "type", None) == "filename" and v.value:
                files.add(v.value)
                if is_tiled_path(v.value):
                    files.update(discover_tiles(v.value).values())
    return sorted(files)


def content_hash(compiled, cfg, allow_missing_textures: bool = False, extra: str = "",
                 measured: str | None = None) -> str:
    """Hex sha256 of what a material trains to, without its name (see the module docstring).

    ``extra`` adds settings that live outside ``cfg`` (an error budget). ``measured``: the MERL file of a
    measured BRDF (``compiled`` is then None), hashed by its bytes.
    """
    h = hashlib.sha256()

    def put(tag: str, text: str) -> None:
        data = text.encode()
        h.update(f"{tag}:{len(data)}:".encode() + data)

    put("format", str(FORMAT_VERSION))
    put("training", str(TRAINING_VERSION))
    if measured is not None:
        put("measured", file_digest(measured))
    else:
        put("graph", graph_text(compiled))
        for f in graph_files(compiled):
            put("file", f)
            put("digest", file_digest(f) if os.path.isfile(f) else "missing")
    put("allow_missing_textures", str(bool(allow_missing_textures)))
    put("settings", json.dumps(settings_for_hash(cfg), sort_keys=True, default=str))
    put("ocio", os.environ.get("OCIO", ""))
    put("extra", extra)
    return h.hexdigest()


def cached_record(folder, digest: str) -> MaterialRecord | None:
    """The stored record of ``folder`` when its source hash is ``digest`` and its checkpoint exists (None:
    no record of this version, another hash, or no checkpoint: the material trains again)."""
    record = read_record_or_none(folder)
    if record is None or record.source_hash != digest or not (Path(folder) / "checkpoint.pt").is_file():
        return None
    return record
