"""What every command may write: the rules that keep ``convert``, ``report`` and ``render`` from
overwriting or deleting anything they did not create.

A command's outputs are checked here before anything is computed, and any refusal is an
:class:`~mtlx2neural.errors.InputError` (exit 2) that names the path, says why, and says that
nothing was written:

- **never an input**: no output is the asset, a file the asset reads (sublayers, references,
  payloads, ``xi:include``\\ s, textures: :func:`mtlx2neural.scene.dependencies.input_files`), or
  a folder that holds one (:func:`refuse_inputs`);
- **never an export**: no output lands inside a conversion's output folder (a folder marked with
  :data:`FOLDER_MARKER`, :func:`conversion_folder_of`) or on a neural layer, unless the command is
  the conversion writing that folder (:mod:`.layout`);
- **folders are claimed, not taken**: a folder that a command replaces whole must be empty or
  carry that command's own marker (:func:`claim_report_folder` for ``report -o``; the conversion's
  output folder: :func:`mtlx2neural.pipeline.layout.check_output`).

Single files are then written atomically (:mod:`mtlx2neural.atomic`) and folders through
:class:`mtlx2neural.staging.Staging` (all at once, crash-safe).
"""

from __future__ import annotations

import json
from pathlib import Path

from mtlx2neural.errors import InputError
from mtlx2neural.export.usd_writer import LEGACY_DOC_PREFIX, RECORD_KEY
from mtlx2neural.scene.dependencies import canonical

FOLDER_MARKER = ".mtlx2neural.json"
"""The file that marks a conversion's output folder: ``{"source": input path, "tool": version}``."""

REPORT_MARKER = ".mtlx2neural-report.json"
"""The file that marks a folder written by ``mtlx2neural report``: ``{"layer": path, "tool": version}``."""


def refuse(what: str, how: str = "choose another output with -o") -> InputError:
    """The refusal of an output: ``what`` is wrong; nothing was written; ``how`` to choose another."""
    return InputError(f"{what}. Nothing was written; {how}")


EXPORT_RECORD = "export.json"
"""The record in every material's exported ``neural/`` folder (:mod:`mtlx2neural.export.bundle`)."""


def conversion_folder_of(path) -> Path | None:
    """The conversion output folder (marked with :data:`FOLDER_MARKER`) or exported ``neural/``
    folder (holding :data:`EXPORT_RECORD`) that holds ``path``, or None."""
    for parent in canonical(path).parents:
        if (parent / FOLDER_MARKER).is_file() or (parent / EXPORT_RECORD).is_file():
            return parent
    return None


def is_neural_layer(path) -> bool:
    """Is the existing file ``path`` a layer that mtlx2neural wrote (its ``customLayerData`` record)?"""
    from pxr import Sdf  # Local: USD is imported only when a layer is to be read

    path = Path(path)
    if not path.is_file():
        return False
    try:
        head = Sdf.Layer.OpenAsAnonymous(str(path), True)  # the header only
    except Exception:  # noqa: BLE001 - any unreadable file is "not a neural layer" here
        return False
    return head is not None and (RECORD_KEY in dict(head.customLayerData)
                                 or (head.documentation or "").startswith(LEGACY_DOC_PREFIX))


def refuse_inputs(target, kind: str, inputs: set[Path], asset, how: str = "choose another output with -o") -> None:
    """Refuse ``target`` (a file or folder this command would write; ``kind`` says which output it is)
    when it is one of ``inputs`` (the files ``asset`` reads) or a folder holding one."""
    target = canonical(target)
    asset = canonical(asset)

    def role(p: Path) -> str:
        return f"the input {p}" if p == asset else f"{p}, a file the input {asset.name} reads"

    if target in inputs:
        raise refuse(f"{target}: {kind} would overwrite {role(target)}", how)
    inside = sorted(p for p in inputs if target in p.parents)
    if inside:
        raise refuse(f"{target}: {kind} is a folder that holds {role(inside[0])}, which it would replace", how)


def check_render_outputs(outputs: list[Path], inputs: set[Path], asset) -> None:
    """Refuse a render whose files (the EXR and the PNG beside it) would land on an input of the
    asset, inside a conversion's output folder, or on a neural layer."""
    how = "choose another -o OUT.exr (the PNG is written beside it, with the same name)"
    for out in outputs:
        refuse_inputs(out, "an output of the render", inputs, asset, how)
        export = conversion_folder_of(out)
        if export is not None:
            raise refuse(f"{canonical(out)}: an output of the render would land inside {export}, the output "
                         f"folder of a conversion, whose files it could overwrite", how)
        if is_neural_layer(out):
            raise refuse(f"{canonical(out)}: an output of the render would overwrite a neural layer", how)


def is_report_folder(folder: Path) -> bool:
    """Does ``folder`` hold a report of ours: the marker, or (reports written before it) only
    ``index.html``, ``report.json`` and PNGs?"""
    if (folder / REPORT_MARKER).is_file():
        return True
    names = {p.name for p in folder.iterdir()}
    return {"index.html", "report.json"} <= names and all(
        n in ("index.html", "report.json") or (n.endswith(".png") and (folder / n).is_file()) for n in names)


def claim_report_folder(out, inputs: set[Path], layer) -> None:
    """Refuse a report folder ``out`` that is, or holds, an input of the layer; lies inside a
    conversion's output folder; is a file; or is a non-empty folder that is not an earlier report
    (:func:`is_report_folder`). An earlier report is replaced whole, atomically."""
    out = canonical(out)
    how = "choose another report folder with -o (a new or empty folder, or an earlier report)"
    refuse_inputs(out, "the report folder", inputs, layer, how)
    export = conversion_folder_of(out)
    if export is not None or (out / FOLDER_MARKER).is_file():
        raise refuse(f"{out}: the report folder would lie in a conversion's output folder ({export or out})", how)
    if out.exists() and not out.is_dir():
        raise refuse(f"{out}: the report folder's path is a file", how)
    if out.is_dir() and any(out.iterdir()) and not is_report_folder(out):
        raise refuse(f"{out}: the report folder already holds files that mtlx2neural report did not write "
                     f"(no {REPORT_MARKER}), and the report replaces the whole folder", how)


def report_marker(layer, tool_version: str) -> str:
    """The text of :data:`REPORT_MARKER` for a report of ``layer``."""
    return json.dumps({"layer": str(canonical(layer)), "tool": f"mtlx2neural {tool_version}"}) + "\n"
