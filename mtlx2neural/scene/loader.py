"""Entry points of the scene stage: dispatch on the file type (or take an open ``Usd.Stage``), select, convert."""

from __future__ import annotations

import os
import re

import MaterialX as mx

from mtlx2neural.errors import InputError
from mtlx2neural.formats.merl import read_merl
from mtlx2neural.scene import mtlx_file, usd_stage
from mtlx2neural.scene.materials import (
    Candidate,
    MaterialSource,
    SceneMaterials,
    choose,
)

MTLX_EXTENSIONS = (".mtlx",)
MEASURED_EXTENSIONS = (".binary",)
"""Measured BRDFs: MERL tables (:mod:`mtlx2neural.formats.merl`)."""


def _candidates(path) -> tuple[str, list[Candidate]]:
    if usd_stage.is_stage(path):
        return usd_stage.stage_name(path), usd_stage.candidates(path)
    asset = os.path.abspath(os.fspath(path))
    ext = os.path.splitext(asset)[1].lower()
    if os.path.isdir(asset) and ext not in MTLX_EXTENSIONS + usd_stage.USD_EXTENSIONS:  # a folder of measured BRDFs: one material per MERL file
        tables = sorted(f for f in os.listdir(asset) if f.lower().endswith(MEASURED_EXTENSIONS))
        if not tables:
            raise InputError(f"{asset}: a folder, and it holds no measured BRDF ({', '.join(MEASURED_EXTENSIONS)} "
                             f"files); give a MaterialX or USD file, a MERL file, or a folder of MERL files")
        return asset, [_measured_candidate(os.path.join(asset, f)) for f in tables]
    if ext in MTLX_EXTENSIONS:
        return asset, _mtlx_candidates(asset)
    if ext in usd_stage.USD_EXTENSIONS:
        return asset, usd_stage.candidates(asset)
    if ext in MEASURED_EXTENSIONS:
        return asset, [_measured_candidate(asset)]
    supported = ", ".join(MTLX_EXTENSIONS + usd_stage.USD_EXTENSIONS + MEASURED_EXTENSIONS)
    raise InputError(
        f"{asset}: unsupported file type {ext or '(no extension)'!r}. Give a MaterialX or USD file, or a "
        f"measured BRDF ({supported})."
    )


def _measured_candidate(asset: str) -> Candidate:
    """The one material of a MERL file, named after the file (its stem made a valid identifier). Loading
    reads the table, so a malformed file fails there, naming itself."""
    stem = os.path.splitext(os.path.basename(asset))[0]
    name = re.sub(r"\W", "_", stem) if stem else "measured"
    name = f"m_{name}" if name[0].isdigit() else name

    def load() -> MaterialSource:
        read_merl(asset)  # InputError naming the file when it is missing or malformed
        return MaterialSource(name=name, document=None, material=name, source_file=asset, measured=True)

    return Candidate(key=name, aliases=(stem,), reason=None, load=load)


def _mtlx_candidates(asset: str) -> list[Candidate]:
    """A candidate per material of the file. An invalid document fails whole, unless the fault lies
    in some materials' own graphs and others are valid: those others still load (as a USD stage's
    materials do), and each faulty one raises its own error when loaded."""
    try:
        doc, errors = mtlx_file.read_document(asset), {}
    except InputError as whole:
        doc = mtlx_file.read_document(asset, validate=False)  # an unreadable file raises again
        errors = mtlx_file.material_errors(doc, asset)
        if not any(errors.values()) or all(errors.values()):
            raise whole from None
    return [
        Candidate(key=name, aliases=(name,), reason=None, load=_mtlx_loader(asset, doc, name, errors.get(name),
                                                                            pruned=bool(errors)))
        for name in mtlx_file.material_names(doc)
    ]


def _mtlx_loader(asset: str, doc: "mx.Document", name: str, error: InputError | None = None, pruned: bool = False):
    def load() -> MaterialSource:
        if error is not None:
            raise error
        if pruned:  # the file is invalid elsewhere: this material's own part of it
            own = mtlx_file.material_document(doc, name)
        else:
            own = mx.createDocument()
            own.copyContentFrom(doc)
        return MaterialSource(name=name, document=own, material=name, source_file=asset, bound_prims=[])

    return load


def load_asset(path, keep_going: bool = False) -> SceneMaterials:
    """Find and convert every material that the asset's renderable geometry uses.

    ``path`` is a ``.mtlx`` file (every ``surfacematerial`` is a material), a measured BRDF
    (a MERL ``.binary`` file: one material, named after the file; a folder: one per such file in it),
    or a USD file (``.usd``/``.usda``/``.usdc``/``.usdz``), whose Materials are
    selected only when bound to visible gprims of purpose ``default`` or
    ``render``; the others are listed in ``skipped`` with the reason. ``path``
    may also be an open ``Usd.Stage`` (in memory or not): its composed scene,
    unsaved and session-layer edits included, is read the same way through a
    private view (:func:`~mtlx2neural.scene.usd_stage.stage_view`; the stage
    itself is not changed). Each
    selected material is converted to its own MaterialX document. Nothing is
    written to disk. Raises InputError for missing, malformed or unsupported
    input; with ``keep_going``, a selected material whose own network cannot be read
    (an InputError while converting it) is listed in ``failed`` instead, and the
    others are still returned.
    """
    asset, cands = _candidates(path)
    materials, failed = [], []
    for c in cands:
        if c.reason is not None:
            continue
        try:
            materials.append(c.load())
        except InputError as exc:
            if not keep_going:
                raise
            failed.append((c.key, exc))
    skipped = [(c.key, c.reason) for c in cands if c.reason is not None]
    return SceneMaterials(asset=asset, materials=materials, skipped=skipped, failed=failed)


def find_material(path, material: str | None = None) -> MaterialSource:
    """Return one material of the asset at ``path`` (a file, or an open ``Usd.Stage`` as for
    :func:`load_asset`) as a MaterialX document.

    ``material`` may be a full USD prim path (``/World/Looks/Brass``), a prim
    or surfacematerial name (``Brass``), or None for the only material that
    renderable geometry uses. A material named explicitly is returned even
    when no renderable geometry binds it. Raises InputError (listing the
    choices) when the name is unknown or ambiguous, or when ``material`` is
    None and the asset does not have exactly one selected material.
    """
    asset, cands = _candidates(path)
    return choose(asset, cands, material).load()
