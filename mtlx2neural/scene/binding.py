"""Which materials renderable geometry actually uses.

A prim is *renderable* when it is a ``UsdGeom.Gprim`` (or a ``materialBind``
GeomSubset of one) that is visible (``ComputeVisibility() != invisible``) and
whose computed purpose is ``default`` or ``render``. Bindings are resolved by
``UsdShade.MaterialBindingAPI.ComputeBoundMaterials`` for the ``full``
material purpose, which falls back to all-purpose bindings and handles
direct, collection-based and inherited (ancestor) bindings. Instance proxies
are included, so instanced geometry counts.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from pxr import Usd, UsdGeom, UsdShade

RENDER_PURPOSES = (UsdGeom.Tokens.default_, UsdGeom.Tokens.render)

NO_GEOMETRY = "stage has no renderable geometry"
NOT_BOUND = "not bound to any renderable prim"
ONLY_INVISIBLE = "bound only to invisible prims"
ONLY_NON_RENDER = "bound only to proxy/guide prims"
ONLY_HIDDEN = "bound only to invisible or proxy/guide prims"


@dataclass
class MaterialUse:
    """The gprims (or GeomSubsets) bound to one material, by renderability."""

    renderable: list[str] = field(default_factory=list)
    invisible: list[str] = field(default_factory=list)
    non_render: list[str] = field(default_factory=list)  # proxy or guide purpose


@dataclass
class Bindings:
    """Result of :func:`collect_bindings`."""

    has_geometry: bool  # the stage has at least one Gprim (of any visibility/purpose)
    uses: dict[str, MaterialUse]  # material prim path -> use


def _bindable_prims(stage: Usd.Stage):
    """Yield ``(prim, gprim)`` for every Gprim and every materialBind GeomSubset of one."""
    predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
    for prim in stage.Traverse(predicate):
        if not prim.IsA(UsdGeom.Gprim):
            continue
        yield prim, prim
        for subset in UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets():
            yield subset.GetPrim(), prim


def collect_bindings(stage: Usd.Stage, purpose: str = UsdShade.Tokens.full) -> Bindings:
    """Resolve the bound material of every gprim on ``stage`` and classify the gprim.

    ``purpose`` is the *material* binding purpose (``full`` by default, which
    falls back to all-purpose bindings).
    """
    pairs = list(_bindable_prims(stage))
    uses: dict[str, MaterialUse] = {}
    if not pairs:
        return Bindings(False, uses)
    prims = [p for p, _ in pairs]
    materials, _ = UsdShade.MaterialBindingAPI.ComputeBoundMaterials(prims, purpose)
    state: dict[str, str] = {}
    for (prim, gprim), material in zip(pairs, materials, strict=True):
        if not material or not material.GetPrim().IsValid():
            continue
        key = str(gprim.GetPath())
        if key not in state:
            state[key] = _classify(UsdGeom.Imageable(gprim))
        use = uses.setdefault(str(material.GetPath()), MaterialUse())
        getattr(use, state[key]).append(str(prim.GetPath()))
    return Bindings(True, uses)


def _classify(imageable: UsdGeom.Imageable) -> str:
    if imageable.ComputeVisibility() == UsdGeom.Tokens.invisible:
        return "invisible"
    if imageable.ComputePurpose() not in RENDER_PURPOSES:
        return "non_render"
    return "renderable"


def skip_reason(bindings: Bindings, material_path: str) -> str | None:
    """Why the material at ``material_path`` is not needed, or None when renderable geometry uses it."""
    if not bindings.has_geometry:
        return NO_GEOMETRY
    use = bindings.uses.get(material_path)
    if use is None:
        return NOT_BOUND
    if use.renderable:
        return None
    if use.invisible and use.non_render:
        return f"{ONLY_HIDDEN}: {_examples(use.invisible + use.non_render)}"
    if use.invisible:
        return f"{ONLY_INVISIBLE}: {_examples(use.invisible)}"
    return f"{ONLY_NON_RENDER}: {_examples(use.non_render)}"


def _examples(paths: list[str], limit: int = 3) -> str:
    shown = ", ".join(paths[:limit])
    return shown + (f" and {len(paths) - limit} more" if len(paths) > limit else "")
