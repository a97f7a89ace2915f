"""Where a conversion writes, decided and checked before any training.

Layout (:func:`resolve_output`): ``-o`` names either the output **folder** (``OUT``;
the layer is then its sibling ``OUT.usda``) or the **layer** (a path ending in
``.usda``, ``.usd`` or ``.usdc``; the folder is then that path without its
suffix). The default is ``<asset folder>/<asset stem>_neural``. Each material's
files go into ``OUT/<material folder>`` (:func:`material_folder`: an escape of the
material's name that two names can never share).

Safety (:func:`check_output`), before anything is written:

1. nothing the run writes (the layer, the folder, a material folder) is the input
   or a file the input reads (its sublayers, references, payloads, ``xi:include``s
   and textures: :func:`mtlx2neural.scene.dependencies.input_files`), and the
   output folder contains none of them;
2. an existing layer at the layer path was written by mtlx2neural (the
   ``customLayerData`` record :data:`~.usd_writer.RECORD_KEY`) for this same input
   (or for a stage snapshot in this output folder, :data:`SNAPSHOT_NAME`: an earlier
   conversion of an open stage with unsaved edits);
3. an existing output folder is empty or carries this tool's marker file
   (:data:`FOLDER_MARKER`; folders written before the marker existed are recognised
   by their ``summary.json`` files).

Any failure is an :class:`~mtlx2neural.errors.InputError` (exit 2) that names the
path and says how to choose another. :func:`prepare_folder` then creates the folder,
proves it (and the layer's folder) writable with a real file, and marks it.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

from mtlx2neural.errors import InputError
from mtlx2neural.export.usd_writer import LEGACY_DOC_PREFIX, RECORD_KEY
from mtlx2neural.pipeline.output_safety import FOLDER_MARKER, refuse, refuse_inputs
from mtlx2neural.scene.dependencies import canonical

LAYER_SUFFIXES = (".usda", ".usd", ".usdc")
"""``-o`` values with these suffixes name the layer, not the folder."""

SNAPSHOT_NAME = "stage-snapshot.usda"
"""The flattened snapshot of an in-memory or edited ``Usd.Stage`` input, in the output folder
(:mod:`mtlx2neural.scene.snapshot`). No material folder can have this name: ``-`` appears in
those only as ``-<hex digits>-`` or before a hash, and "snapshot" is not hex."""


MAX_FOLDER_NAME = 120
"""Longer escaped names are cut and end in a hash of the full name (file systems allow 255 bytes)."""


def material_folder(name: str) -> str:
    """The folder name of the material ``name`` (a prim path or a MaterialX name).

    Readable and injective: ASCII letters, digits and ``_`` stay, each ``/`` between
    path components becomes ``.``, and any other character ``c`` becomes
    ``-<hex code of c>-``; so ``/World/Looks_A/Paint`` -> ``World.Looks_A.Paint`` and
    ``/World/Looks/A_Paint`` -> ``World.Looks.A_Paint``. The leading ``/`` of a prim
    path is dropped. A name longer than :data:`MAX_FOLDER_NAME` is cut and ends in
    ``-`` and 12 hex digits of its SHA-256.
    """
    out = []
    for ch in name.lstrip("/"):
        if ch.isascii() and (ch.isalnum() or ch == "_"):
            out.append(ch)
        elif ch == "/":
            out.append(".")
        else:
            out.append(f"-{ord(ch):x}-")
    text = "".join(out) or "material"
    if len(text) > MAX_FOLDER_NAME:
        text = f"{text[:MAX_FOLDER_NAME - 13]}-{_short_hash(name)}"
    return text


def _short_hash(name: str) -> str:
    return hashlib.sha256(name.encode()).hexdigest()[:12]


def material_folders(names) -> dict[str, str]:
    """:func:`material_folder` of each name, made unique on case-insensitive file systems: names
    whose folders differ only in case end in ``-`` and a hash of the name."""
    folders = {n: material_folder(n) for n in names}
    by_lower: dict[str, list[str]] = {}
    for n, f in folders.items():
        by_lower.setdefault(f.lower(), []).append(n)
    for group in by_lower.values():
        if len(group) > 1:
            for n in group:
                folders[n] = f"{folders[n]}-{_short_hash(n)}"
    return folders


@dataclass(frozen=True)
class OutputLayout:
    """The conversion's output folder and its USD layer (absolute paths)."""

    folder: Path
    layer: Path


def default_output(asset) -> Path:
    """``<asset folder>/<asset stem>_neural``."""
    asset = Path(asset).resolve()
    return asset.parent / f"{asset.stem}_neural"


def resolve_output(asset, out=None) -> OutputLayout:
    """The layout for ``-o out`` (None: :func:`default_output`); see the module docstring."""
    out = Path(out) if out else default_output(asset)
    out = Path(os.path.abspath(out))
    if out.suffix.lower() in LAYER_SUFFIXES:
        return OutputLayout(folder=out.with_suffix(""), layer=out)
    return OutputLayout(folder=out, layer=out.parent / f"{out.name}.usda")


@dataclass
class LayerRecord:
    """What an existing neural layer says about itself (its ``customLayerData`` record)."""

    source: Path | None
    """The input it was written for (None: not recorded, a layer of mtlx2neural 0.2 or older)."""
    materials: dict[str, dict]
    """Material name -> ``{"prim", "sourceHash", "folder"}`` (paths as recorded: relative to the layer)."""


def names_entry(material: str, name: str | None, prim: str | None) -> bool:
    """Whether ``material`` (as a user gives it: a recorded material name, a prim path with or without its
    leading ``/``, or a prim name) names the layer record's entry ``name``, whose Material is at ``prim``."""
    prim = prim or ""
    return material in (name, prim, prim.rsplit("/", 1)[-1]) or (bool(prim) and "/" + material.lstrip("/") == prim)


def read_layer_record(layer: Path) -> LayerRecord | None:
    """The record of the mtlx2neural layer at ``layer``; None when the file is not one (or not USD)."""
    # Local: pxr loads USD's plugins on import (about 0.15 s); only USD work needs it.
    from pxr import Sdf

    try:
        opened = Sdf.Layer.OpenAsAnonymous(str(layer))  # not the registry's copy, which may be stale
    except Exception:  # noqa: BLE001 - any unreadable or foreign file is "not ours"
        return None
    if opened is None:
        return None
    data = dict(opened.customLayerData).get(RECORD_KEY)
    if isinstance(data, dict):
        source = data.get("source")
        src = canonical(layer.parent / source) if source else None
        return LayerRecord(src, {k: dict(v) for k, v in dict(data.get("materials") or {}).items()})
    if (opened.documentation or "").startswith(LEGACY_DOC_PREFIX):
        return LayerRecord(None, {})
    return None


def _is_our_folder(folder: Path) -> bool:
    if (folder / FOLDER_MARKER).is_file():
        return True
    # Folders written before the marker: every other entry is a material folder with a summary.
    entries = [p for p in folder.iterdir() if not p.name.startswith(".mtlx2neural")]  # lock, staging
    return all(p.is_dir() and (p / "summary.json").is_file() for p in entries)


def _refuse(what: str) -> InputError:
    return refuse(what, "choose another output with -o (a folder, or a layer path ending in .usda/.usd/.usdc)")


def check_output(layout: OutputLayout, asset, inputs: set[Path], folders: list[Path]) -> LayerRecord | None:
    """Refuse (:class:`InputError`) an output that could overwrite the input or another tool's files
    (module docstring; the rules shared by every command: :mod:`.output_safety`); returns the existing
    layer's record, or None when there is no layer yet."""
    asset = canonical(asset)
    layer, folder = canonical(layout.layer), canonical(layout.folder)
    how = "choose another output with -o (a folder, or a layer path ending in .usda/.usd/.usdc)"
    for target, kind in [(layer, "the USD layer of this run"), (folder, "the output folder")] + [
            (canonical(f), "a material folder of this run") for f in folders]:
        refuse_inputs(target, kind, inputs, asset, how)
    record = None
    if layer.exists() or layer.is_symlink():
        record = None if layer.is_dir() else read_layer_record(layer)
        if record is None:
            raise _refuse(f"{layer}: a file that mtlx2neural did not write is already there (it carries no "
                          f"'{RECORD_KEY}' record in its customLayerData), and the USD layer would replace it")
        if record.source is not None and record.source not in (asset, canonical(layout.folder / SNAPSHOT_NAME)):
            raise _refuse(f"{layer}: this neural layer was written for another input ({record.source}), and "
                          f"this run would replace it")
    if folder.exists() and not folder.is_dir():
        raise _refuse(f"{folder}: the output folder's path is a file")
    if folder.is_dir() and any(folder.iterdir()) and not _is_our_folder(folder):
        raise _refuse(f"{folder}: the output folder already holds files that mtlx2neural did not write "
                      f"(no {FOLDER_MARKER})")
    for f in folders:
        if Path(f).exists() and not Path(f).is_dir():
            raise _refuse(f"{f}: a material folder's path is a file")
    return record


def probe_writable(folder: Path) -> None:
    """Create ``folder`` (and its parents) and write and remove a file in it; an unwritable folder is
    an :class:`InputError` naming it, found before any training."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".mtlx2neural-probe-", dir=folder)
        os.close(fd)
        os.unlink(tmp)
    except OSError as exc:
        raise InputError(f"{folder}: cannot write there ({exc.strerror or exc}); nothing was trained. Choose a "
                         f"writable output with -o, or fix the folder's permissions") from None


def prepare_folder(layout: OutputLayout, asset, tool_version: str) -> None:
    """Create and mark the output folder and prove both it and the layer's folder writable."""
    probe_writable(layout.layer.parent)
    probe_writable(layout.folder)
    marker = layout.folder / FOLDER_MARKER
    if not marker.is_file():
        tmp = marker.with_name(f"{marker.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps({"source": str(canonical(asset)), "tool": f"mtlx2neural {tool_version}"}) + "\n")
        os.replace(tmp, marker)


WORK_FOLDER = ".mtlx2neural-work"
"""Where a run trains: ``OUT/.mtlx2neural-work/<material folder>``. A material's training files
(checkpoint, curves, summary, PNGs, baseline) reach ``OUT/<material folder>`` only with its
export, in one commit (:mod:`mtlx2neural.staging`), so a run that fails or is killed before
then leaves the previous files, records and export as they were."""


def work_folder(folder) -> Path:
    """The folder a material whose final folder is ``folder`` trains in (:data:`WORK_FOLDER`)."""
    folder = Path(folder)
    return folder.parent / WORK_FOLDER / folder.name


def prepare_work_folder(folder, resume: bool) -> Path:
    """A work folder (:func:`work_folder`) to train ``folder``'s material in: empty, or with ``resume``
    holding the checkpoint to continue (an interrupted run's, kept there, else the final folder's)."""
    import shutil

    work = work_folder(folder)
    if not resume:
        shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True, exist_ok=True)
    saved = Path(folder) / "checkpoint.pt"
    if resume and not (work / "checkpoint.pt").is_file() and saved.is_file():
        shutil.copyfile(saved, work / "checkpoint.pt")
    return work
