"""Which MaterialX node categories the compiler supports, found by compiling every nodedef.

:func:`coverage` walks every nodedef of MaterialX's standard data libraries (stdlib, pbrlib, bxdf, cmlib,
nprlib, lights), writes a one-node document per nodedef with the nodedef's defaults, and compiles it as a
material input would be: expanded into torch operators and closures (whose lobes come from
:mod:`mtlx2neural.reference`); whether the values are right is the oracle tests' part.  A category is
``supported`` when every nodedef compiles, ``partial`` when some do, ``unsupported`` when none does, and
``out of scope`` for the families the tool does not model at all (hair, volumes, light shaders,
displacement, OSL-only nodes).  The surfacematerial node is the material root every conversion starts from.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import MaterialX as mx

from mtlx2neural.errors import InputError, UnsupportedNodeError
from mtlx2neural.graph.compile import NATIVE
from mtlx2neural.graph.expand import Expander, _drive, _Scope
from mtlx2neural.graph.ir import Const
from mtlx2neural.graph.library import standard_library

__all__ = ["CategoryCoverage", "OUT_OF_SCOPE", "coverage", "coverage_summary", "format_coverage"]

_HAIR = "hair is not a surface BRDF"
_VOLUME = "volumes are not surface reflectance"
_LIGHT = "light shaders are not materials"
OUT_OF_SCOPE = {
    "chiang_hair_bsdf": _HAIR, "chiang_hair_roughness": _HAIR, "chiang_hair_absorption_from_color": _HAIR,
    "deon_hair_absorption_from_melanin": _HAIR,
    "volume": _VOLUME, "volumematerial": _VOLUME, "absorption_vdf": _VOLUME, "anisotropic_vdf": _VOLUME,
    "light": _LIGHT, "point_light": _LIGHT, "directional_light": _LIGHT, "spot_light": _LIGHT,
    "displacement": "displacement moves geometry; a reflectance model cannot bake it",
    "osl_set_ci": "an OSL-only node (sets Ci)",
}
ROOTS = {"surfacematerial": "the material root every conversion starts from"}


@dataclass(frozen=True)
class CategoryCoverage:
    """One node category: its library (stdlib, pbrlib...), status, nodedef counts and a reason."""

    category: str
    library: str
    status: str  # "supported", "partial", "unsupported" or "out of scope"
    nodedefs: int
    compiled: int
    reason: str = ""


def _library_of(nodedef: mx.NodeDef) -> str:
    uri = nodedef.getSourceUri() or ""
    tail = uri.replace("\\", "/").split("libraries/")[-1]
    return tail.split("/")[0] if "/" in tail else "?"


def _compile_nodedefs(nodedefs: list[mx.NodeDef]) -> dict[str, str]:
    """{nodedef name: "" when a node of it (inputs at their defaults) expands into torch operators and
    closures, else the reason it does not}.  One document holds a node per nodedef, expanded by one
    :class:`~mtlx2neural.graph.expand.Expander` (the libraries are imported once)."""
    doc = mx.createDocument()
    names = {}
    for k, nd in enumerate(nodedefs):
        outputs = nd.getActiveOutputs()
        node = doc.addNode(nd.getNodeString(), f"n{k}", outputs[0].getType() if len(outputs) == 1 else "multioutput")
        node.setNodeDefString(nd.getName())
        names[nd.getName()] = (node.getName(), outputs[0])
    exp = Expander(doc, NATIVE)
    scope = _Scope(exp.doc, "")
    result = {}
    for nd_name, (node_name, out) in names.items():
        try:
            got = _drive(exp._node_output(scope, node_name, out.getName()))
            strings = ("string", "filename")
            # A string output counts when it folds to a constant (an image's file can read it).
            result[nd_name] = ("" if out.getType() not in strings or isinstance(got, Const) else
                               f"output type {out.getType()} (a string, not a shading value)")
        except (UnsupportedNodeError, InputError) as exc:
            result[nd_name] = str(exc)
        except Exception as exc:  # a value the expansion cannot read (matrices) is not supported either
            result[nd_name] = f"{type(exc).__name__}: {str(exc).splitlines()[0]}"
    return result


@functools.lru_cache(maxsize=1)
def coverage() -> dict[str, CategoryCoverage]:
    """Every node category of MaterialX's standard libraries -> :class:`CategoryCoverage` (computed once per
    process: about a thousand nodes expanded, a few seconds)."""
    by_category: dict[str, list[mx.NodeDef]] = {}
    for nd in standard_library().getNodeDefs():
        by_category.setdefault(nd.getNodeString(), []).append(nd)
    in_scope = [nd for c, nds in by_category.items() if c not in OUT_OF_SCOPE and c not in ROOTS for nd in nds]
    reasons = _compile_nodedefs(in_scope)
    result = {}
    for category, nds in sorted(by_category.items()):
        library = _library_of(nds[0])
        if category in OUT_OF_SCOPE:
            result[category] = CategoryCoverage(category, library, "out of scope", len(nds), 0,
                                                OUT_OF_SCOPE[category])
            continue
        if category in ROOTS:
            result[category] = CategoryCoverage(category, library, "supported", len(nds), len(nds),
                                                ROOTS[category])
            continue
        failures = [(nd.getName(), reasons[nd.getName()]) for nd in nds if reasons[nd.getName()]]
        compiled = len(nds) - len(failures)
        status = "supported" if not failures else ("partial" if compiled else "unsupported")
        reason = "" if not failures else f"{failures[0][0]}: {failures[0][1].splitlines()[0][:160]}"
        if failures and len(failures) > 1:
            reason += f" (and {len(failures) - 1} more nodedefs)"
        result[category] = CategoryCoverage(category, library, status, len(nds), compiled, reason)
    return result


def coverage_summary(libraries: tuple[str, ...] | None = ("stdlib", "pbrlib")) -> dict:
    """{"supported": n, "partial": n, "unsupported": n, "out_of_scope": n, "in_scope": n} over the
    categories of ``libraries`` (None: all).  ``supported`` counts fully compiled categories."""
    rows = [c for c in coverage().values() if libraries is None or c.library in libraries]
    count = {s: sum(c.status == s for c in rows) for s in ("supported", "partial", "unsupported", "out of scope")}
    return {"supported": count["supported"], "partial": count["partial"], "unsupported": count["unsupported"],
            "out_of_scope": count["out of scope"], "in_scope": len(rows) - count["out of scope"]}


def format_coverage() -> str:
    """A plain-text table of :func:`coverage` with the figures per library."""
    rows = sorted(coverage().values(), key=lambda c: (c.library, c.status != "supported", c.category))
    lines = [f"{'category':34} {'library':8} {'status':13} nodedefs  reason"]
    for c in rows:
        lines.append(f"{c.category:34} {c.library:8} {c.status:13} {c.compiled:>3}/{c.nodedefs:<4}  {c.reason}")
    for libs, label in ((("stdlib", "pbrlib"), "stdlib + pbrlib"), (None, "all libraries")):
        s = coverage_summary(libs)
        lines.append(f"{label}: {s['supported']} of {s['in_scope']} in-scope categories supported "
                     f"({s['partial']} partly, {s['unsupported']} not; {s['out_of_scope']} out of scope)")
    return "\n".join(lines)
