"""The scene stage's result types, and choosing one material by name."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, Sequence

from mtlx2neural.errors import InputError

if TYPE_CHECKING:  # pragma: no cover
    import MaterialX as mx


@dataclass
class MaterialSource:
    """One material to compile, as a self-contained MaterialX document."""

    name: str
    """USD Material prim path (``/World/Looks/Brass``), or the surfacematerial node name for ``.mtlx`` input."""
    document: "mx.Document | None"
    """MaterialX document holding only the user's content (standard libraries not imported);
    ``filename`` values are absolute paths. None for a measured BRDF (``measured``)."""
    material: str
    """Name of the ``surfacematerial`` node inside ``document``."""
    source_file: str
    """Absolute path of the file the network was read from (``.usda``/``.usdc``/``.mtlx``), for messages
    and for loading it again; for a network defined in an in-memory layer, that layer's identifier
    (``anon:...``), which a conversion replaces with its snapshot of the stage."""
    bound_prims: list[str] = field(default_factory=list)
    """USD paths of the renderable gprims (or GeomSubsets) bound to it; empty for plain ``.mtlx`` input."""
    network: bool = False
    """True when converted from a UsdShade network of the stage (``source_file`` is then the layer that
    defines the Material); False for a ``.mtlx`` file or a ``.mtlx`` file the stage references."""
    stage_file: str | None = None
    """Absolute path of the USD stage (its root layer) whose meshes ``bound_prims`` names, for geometry a
    graph reads (:mod:`mtlx2neural.scene.uv_raster`); None for ``.mtlx`` input or an in-memory stage."""
    preview_surface: bool = False
    """True when the Material's universal ``outputs:surface`` is a ``UsdPreviewSurface`` shader and is also
    the surface converted (no other ``outputs:mtlx:surface``): the input's own shader is then an exact
    UsdPreviewSurface fallback, kept as it is instead of a fitted one."""
    measured: bool = False
    """True for a measured BRDF (a MERL ``.binary`` table at ``source_file``): ``document`` is then None,
    and the material's reference is :class:`mtlx2neural.reference.measured.MeasuredMaterial`."""


@dataclass
class SceneMaterials:
    """Every material of an asset: the ones renderable geometry needs, and the ones skipped."""

    asset: str
    """Absolute path of the input asset; for an open stage, its root layer's file, or
    ``in-memory stage <identifier>`` when that layer is anonymous."""
    materials: list[MaterialSource]
    """Materials to compile, in stage/document order."""
    skipped: list[tuple[str, str]] = field(default_factory=list)
    """``(material name or prim path, human-readable reason)`` for each material left out."""
    failed: list[tuple[str, Exception]] = field(default_factory=list)
    """``(material name or prim path, InputError)`` for each selected material whose network could not
    be read (only with ``load_asset(..., keep_going=True)``)."""


@dataclass
class Candidate:
    """A material that can be asked for by name before it is converted."""

    key: str  # prim path, or node name for .mtlx input
    aliases: tuple[str, ...]  # other names it answers to (prim name, .mtlx node name)
    reason: str | None  # None when selected, else why it was skipped
    load: Callable[[], MaterialSource]


def choose(asset: str, candidates: Sequence[Candidate], requested: str | None) -> Candidate:
    """Pick the candidate named ``requested`` (a full path or a name), or the only selected one.

    Raises InputError naming ``asset`` and listing the choices when the name
    is unknown or ambiguous, or when ``requested`` is None and there is not
    exactly one selected material.
    """
    if requested is None:
        selected = [c for c in candidates if c.reason is None]
        if len(selected) == 1:
            return selected[0]
        if not selected:
            if not candidates:
                raise InputError(f"{asset}: contains no materials. Give an asset that defines a material.")
            listing = "\n".join(f"  {c.key}: {c.reason}" for c in candidates)
            raise InputError(
                f"{asset}: no material is bound to renderable geometry. Materials found:\n{listing}\n"
                "Name one explicitly (--material NAME) to bake it anyway."
            )
        listing = "\n".join(f"  {c.key}" for c in selected)
        raise InputError(
            f"{asset}: {len(selected)} materials are bound to renderable geometry:\n{listing}\n"
            "Choose one with --material NAME (a prim path or a material name)."
        )
    wanted = requested.strip()
    exact = [c for c in candidates if c.key == wanted or c.key == "/" + wanted.lstrip("/")]
    if len(exact) == 1:
        return exact[0]
    by_alias = [c for c in candidates if wanted in c.aliases]
    if len(by_alias) == 1:
        return by_alias[0]
    if len(by_alias) > 1:
        listing = "\n".join(f"  {c.key}" for c in by_alias)
        raise InputError(
            f"{asset}: the material name {wanted!r} is ambiguous; it matches:\n{listing}\n"
            "Pass the full prim path instead."
        )
    listing = "\n".join(f"  {c.key}" + ("" if c.reason is None else f"  ({c.reason})") for c in candidates)
    raise InputError(f"{asset}: no material named {wanted!r}. Available materials:\n{listing or '  (none)'}")
