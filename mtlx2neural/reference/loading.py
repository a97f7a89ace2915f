"""Load one material of an asset and build its reference BRDF (``mtlx2neural.load_reference``)."""

from __future__ import annotations

from mtlx2neural.graph import compile_material
from mtlx2neural.graph.geometry import bind_geometry
from mtlx2neural.graph.ops import Application
from mtlx2neural.reference.material import ReferenceMaterial
from mtlx2neural.reference.measured import MeasuredMaterial, load_measured
from mtlx2neural.scene import find_material


def application_of(recorded: dict | None) -> Application | None:
    """The instant a conversion baked a material's ``time``/``frame`` nodes at, from its record's
    ``application`` (:attr:`mtlx2neural.material_record.MaterialRecord.application`: ``frame``, ``fps``,
    ...; written when the graph reads them); None when it records none (the graph reads neither:
    frame 1 at 24 fps then)."""
    if not isinstance(recorded, dict) or "frame" not in recorded or "fps" not in recorded:
        return None
    return Application(frame=float(recorded["frame"]), fps=float(recorded["fps"]))


def load_reference(path, material: str | None = None, device: str = "cpu",
                   allow_missing_textures: bool = False, application: Application | None = None
                   ) -> ReferenceMaterial | MeasuredMaterial:
    """Load ``material`` from a ``.mtlx`` file or a USD stage and compile its reference BRDF (a MERL
    ``.binary`` file: its :class:`~mtlx2neural.reference.measured.MeasuredMaterial`).

    ``material`` is a USD material prim path (or prim name) or a MaterialX
    surfacematerial name; it may be omitted when the asset selects exactly one.
    ``allow_missing_textures`` substitutes an image node's declared ``default`` for a
    missing file instead of failing. Tensors live on ``device``. A graph that reads geometry (position,
    normal, primvars) reads the bound meshes rasterised into their UV layout, or the unit sphere for
    ``.mtlx`` input (:func:`mtlx2neural.graph.geometry.bind_geometry`). ``application``: the instant
    ``time``/``frame`` nodes fold to (None: frame 1 at 24 fps; a conversion's ``--frame``/``--fps``,
    which :func:`application_of` reads back from its record).
    """
    src = find_material(path, material)
    if src.measured:  # a MERL table: tabulated, nothing to compile
        return load_measured(src.source_file, device=device)
    compiled = compile_material(src.document, src.material, device=device,
                                allow_missing_textures=allow_missing_textures, application=application)
    compiled.name = src.name
    bind_geometry(compiled, src.stage_file, src.bound_prims)  # position/normal/primvars the graph reads
    return ReferenceMaterial(compiled)
