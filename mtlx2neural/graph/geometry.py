"""Which geometric inputs a material's graph reads, and binding them to their source.

Geometric inputs are ``position``, ``normal``, ``tangent``, ``bitangent`` (each in object or
world space; ``model`` is object), ``geomcolor`` (the ``displayColor`` primvar, ``displayOpacity``
as alpha) and ``geompropvalue`` (a named primvar; the UV primvars ``st``, ``uv``... read the
texture coordinates). :func:`geometry_reads` finds them on the compiled IR (a walk over the live
spatial nodes, no evaluation); :func:`bind_geometry` hands the evaluator a
:class:`~mtlx2neural.scene.uv_raster.GeometrySource` (the bound meshes of a USD stage, or the
unit sphere for ``.mtlx`` input) only when there is one, so a material that reads no geometry is
unchanged and pays nothing.

The frame nodes (``normal``, ``tangent``, ``bitangent``) have two readings. Where their value
only goes to build a closure's shading frame (a BSDF's ``normal``/``tangent``, a ``normalmap``'s
frame, through any maths on the way: standard_surface rotates ``Tworld`` about ``Nworld``), they
are the axes of the local shading frame, z, x and y, since the BSDF is evaluated in that frame.
Where their value goes anywhere else (a ``dotproduct`` masking up-facing surfaces, a triplanar
blend), they are the surface's vectors from the geometry, in the space the node asks for.

UV sets: a material is baked into one UV layout, the one its bound meshes are drawn in (``st``, else a
mesh's first texCoord2 primvar; the sphere's for ``.mtlx`` input), and its latents are read with it.
A texture read through another UV set is kept apart, not merged: that set is a primvar of the bound
meshes, rasterised into the layout like any primvar, so each latent texel holds the material at the
surface point it covers, with the textures read at that point's coordinates in the other set
(:func:`check_uv_sets` binds them). A ``texcoord`` node with ``index`` k > 0 reads the first of
``st<k>``, ``uv<k>``, ``UV<k>``, ``map<k+1>`` (the names USD exporters give extra sets) that every
bound mesh carries; a vector2 ``geompropvalue`` reads its named primvar. A set that is the layout's
reads the layout's uv directly. Errors, naming the material, the node and the set: the ``.mtlx``
sphere (one UV set) and a mesh without the set; a UDIM texture read through another set (UDIM
tiles are chosen from the layout's UVs). The other set's detail is resampled at the latent grid's
resolution in the layout, so a set that tiles much more densely than the layout loses detail.
"""

from __future__ import annotations

from mtlx2neural.errors import InputError
from mtlx2neural.graph.ir import Const, IRGraph, IRNode, Ref
from mtlx2neural.graph.spatial import FRAME_AXES, UV_PRIMVARS, texcoord_index
from mtlx2neural.graph.transforms import CATEGORIES as TRANSFORMS
from mtlx2neural.graph.transforms import object_world
from mtlx2neural.scene.uv_raster import GeometrySource

GEOMETRIC = {"position", "geomcolor", "geompropvalue"} | set(FRAME_AXES)
FRAME_INPUTS = {c: ("normal", "tangent", "bitangent") for c in ("normalmap", "flake2d", "flake3d")}
"""Non-closure nodes whose listed inputs are a shading frame (they output a shading normal)."""
CLOSURE_FRAME_INPUTS = ("normal", "tangent")


def frame_bound(graph: IRGraph) -> list[bool]:
    """Per IR node: whether every use of its value builds a closure's shading frame (a closure's
    ``normal``/``tangent``, a ``normalmap``'s frame, or another such node), so that a frame node
    wired into it is the local frame's axis. Nodes nobody uses are not frame-bound."""
    uses: list[list[tuple[int, str]]] = [[] for _ in graph.nodes]
    for c, node in enumerate(graph.nodes):
        for name, v in node.inputs.items():
            if isinstance(v, Ref):
                uses[v.node].append((c, name))
    bound = [False] * len(graph.nodes)
    for i in reversed(range(len(graph.nodes))):  # consumers come later in topological order
        bound[i] = bool(uses[i]) and all(frame_use(graph, bound, c, name) for c, name in uses[i])
    return bound


def frame_use(graph: IRGraph, bound: list[bool], consumer: int, name: str) -> bool:
    """Whether input ``name`` of node ``consumer`` takes a shading-frame vector (see :func:`frame_bound`)."""
    node = graph[consumer]
    if node.is_closure():
        return name in CLOSURE_FRAME_INPUTS
    return name in FRAME_INPUTS.get(node.category, ()) or bound[consumer]


def frame_read(graph: IRGraph, bound: list[bool], consumer: int, name: str, inp) -> bool:
    """Whether input ``name`` (``inp``) of node ``consumer`` is a frame node read as geometry."""
    return (isinstance(inp, Ref) and graph[inp.node].category in FRAME_AXES
            and not frame_use(graph, bound, consumer, name))


def spaces(node: IRNode) -> tuple[str, str]:
    """(fromspace, tospace) of a ``transform*`` node ("" where not a constant string)."""
    got = []
    for name in ("fromspace", "tospace"):
        inp = node.inputs.get(name)
        got.append(inp.value if isinstance(inp, Const) and isinstance(inp.value, str) else "")
    return got[0], got[1]


def world_transform(graph: IRGraph, bound: list[bool], i: int) -> bool:
    """Whether node ``i`` is a ``transform*`` node between an object space and world whose value is not
    only a shading frame (``bound``: :func:`frame_bound`): it reads the bound prims' object-to-world
    matrix per sample (:mod:`mtlx2neural.graph.transforms`)."""
    node = graph[i]
    return node.category in TRANSFORMS and object_world(*spaces(node)) is not None and not bound[i]


def node_space(node: IRNode) -> str:
    """``object`` or ``world``: the space a geometric node reads (its ``space`` input, or the space of
    the default geometric property it stands for; ``model`` and unknown names are object space)."""
    inp = node.inputs.get("space")
    space = inp.value if isinstance(inp, Const) and isinstance(inp.value, str) else node.attrs.get("space", "")
    return "world" if space == "world" else "object"


def primvar_of(node: IRNode) -> str | None:
    """The primvar a ``geomcolor``/``geompropvalue`` node, or a ``texcoord`` node bound to another UV set,
    reads (None: the layout's UV set or not constant)."""
    if node.category == "geomcolor":
        return "displayColor"
    if node.attrs.get("layout_uv"):
        return None  # the layout's own UV set: the uv itself
    if node.category == "texcoord":
        return node.attrs.get("primvar")  # another UV set, once bound (check_uv_sets)
    gp = node.inputs.get("geomprop")
    if node.category == "geompropvalue" and isinstance(gp, Const) and isinstance(gp.value, str):
        return None if (node.type == "vector2" and gp.value in UV_PRIMVARS) else gp.value
    return None


def geometry_reads(graph: IRGraph, nodes, bound: list[bool] | None = None) -> list[dict]:
    """The geometric inputs spatial ``nodes`` (indices, e.g. ``CompiledMaterial.spatial_nodes``) read:
    ``[{"node", "kind", "space" (frame and position nodes; ``"object to world"`` for a transform node that
    reads the prims' matrix) or "primvar"}]``, one per IR node.
    ``bound``: :func:`frame_bound` of ``graph`` (computed when None)."""
    bound = frame_bound(graph) if bound is None else bound
    seen, out = set(), []

    def add(i):
        if i in seen:
            return
        seen.add(i)
        n = graph[i]
        entry = {"node": n.path, "kind": n.category}
        if n.category in ("position",) + tuple(FRAME_AXES):
            entry["space"] = node_space(n)
        else:
            pv = primvar_of(n)
            if pv is None:
                return
            entry["primvar"] = pv
        out.append(entry)

    for i in nodes:
        n = graph[i]
        if n.category in ("position", "geomcolor", "geompropvalue") or (n.category == "texcoord" and primvar_of(n)):
            add(i)
        if world_transform(graph, bound, i):
            fromspace, tospace = spaces(n)
            out.append({"node": n.path, "kind": n.category, "space": f"{fromspace} to {tospace}"})
        for name, v in n.inputs.items():
            if frame_read(graph, bound, i, name, v):
                add(v.node)
    return out


def texcoord_set_names(index: int) -> tuple[str, ...]:
    """The primvar names a ``texcoord`` node of ``index`` > 0 may read, in the order they are tried."""
    return (f"st{index}", f"uv{index}", f"UV{index}", f"map{index + 1}")


def reads_other_uv_set(node: IRNode) -> bool:
    """Whether ``node`` reads texture coordinates of a UV set that may not be the layout's: a ``texcoord``
    node of index > 0, or a vector2 ``geompropvalue`` of a primvar that is not one of the default UV names."""
    gp = node.inputs.get("geomprop")
    return (node.category == "texcoord" and texcoord_index(node) != 0) or (
        node.category == "geompropvalue" and node.type == "vector2" and isinstance(gp, Const)
        and isinstance(gp.value, str) and gp.value not in UV_PRIMVARS)


def secondary_texcoords(graph: IRGraph, nodes) -> list[int]:
    """The live ``texcoord`` nodes among ``nodes`` that read a UV set other than index 0."""
    return [i for i in nodes if graph[i].category == "texcoord" and reads_other_uv_set(graph[i])]


def image_uv_readers(graph: IRGraph, nodes) -> list[tuple[int, int]]:
    """(consumer, reader) for every node among ``nodes`` with a ``texcoord`` input whose value comes (through
    any maths) from a node that :func:`reads_other_uv_set`."""
    live, found = set(nodes), []
    for c in nodes:
        root = graph[c].inputs.get("texcoord")
        seen, stack = set(), [root.node] if isinstance(root, Ref) else []
        while stack:
            i = stack.pop()
            if i in seen or i not in live:
                continue
            seen.add(i)
            if reads_other_uv_set(graph[i]):
                found.append((c, i))
            stack.extend(v.node for v in graph[i].inputs.values() if isinstance(v, Ref))
    return sorted(found)


def _uv_set_error(compiled, node: IRNode, what: str, why: str) -> InputError:
    return InputError(f"{compiled.source}: material '{compiled.name}' reads {what} (node '{node.path}'): {why}",
                      node=node.path)


def check_uv_sets(compiled, source) -> None:
    """Bind the UV sets other than the layout's that ``compiled`` reads to the bound meshes' primvars
    (``source``, a :class:`~mtlx2neural.scene.uv_raster.GeometrySource`; module docstring): a ``texcoord``
    node of index k > 0 gets ``attrs["primvar"]``, the first of :func:`texcoord_set_names` every mesh
    carries; a set that is the layout's gets ``attrs["layout_uv"]`` (it reads the layout's uv). InputError,
    naming the material, the node and the set, on the sphere, for a set a mesh lacks, and for a UDIM
    texture read through another set."""
    graph, nodes = compiled.graph, compiled.spatial_nodes
    textures = image_uv_readers(graph, nodes)
    readers = sorted(set(secondary_texcoords(graph, nodes)) | {r for _, r in textures})
    if not readers:
        return
    layout = sorted({v for v in source.uv_sets().values() if v})
    names = source.primvar_names()
    for i in readers:
        node = graph[i]
        index = texcoord_index(node) if node.category == "texcoord" else None
        what = f"UV set texcoord index {index}" if index is not None else \
            f"its texture coordinates from the primvar '{node.inputs['geomprop'].value}'"
        if source.is_sphere:
            raise _uv_set_error(compiled, node, what, (
                "a second UV set, which the unit sphere standing in for the geometry of a .mtlx file does not "
                "have (one UV layout, no primvars). Convert a USD stage whose meshes carry that set."))
        wanted = texcoord_set_names(index) if index is not None else (node.inputs["geomprop"].value,)
        primvar = next((w for w in wanted if all(w in have for have in names.values())), None)
        if primvar is None:
            lacking = sorted(p for p, have in names.items() if not any(w in have for w in wanted))
            raise _uv_set_error(compiled, node, what, (
                f"bound mesh{'es' if len(lacking) > 1 else ''} {', '.join(lacking or sorted(names))} "
                f"{'have' if len(lacking) > 1 else 'has'} no primvar {' / '.join(wanted)}. Add that UV set to "
                f"every mesh bound to the material, or read the textures through the layout's set "
                f"({' / '.join(layout) or 'st'})."))
        node.attrs["primvar"] = primvar
        if primvar in layout:
            node.attrs["layout_uv"] = "1"
    for c, i in textures:
        f = graph[c].inputs.get("file")
        if not graph[i].attrs.get("layout_uv") and isinstance(f, Const) and "<UDIM>" in str(f.value):
            raise _uv_set_error(compiled, graph[i], f"UV set '{graph[i].attrs['primvar']}'", (
                f"the UDIM texture '{f.value}' of node '{graph[c].path}' is read through it, but UDIM tiles are "
                f"chosen from the layout's UVs ({' / '.join(layout)}). Read UDIM textures through the layout's set."))


def bind_geometry(compiled, stage_file: str | None = None, prims=()) -> str | None:
    """Give ``compiled``'s evaluator the geometry its graph reads: the meshes ``prims`` of the USD stage
    ``stage_file``, or the unit sphere when there are none (``.mtlx`` input). Returns a one-line note
    (also added to the program's notes), or None when the graph reads no geometry (nothing is bound).
    InputError when another UV set a texture reads cannot be bound (:func:`check_uv_sets`)."""
    source = GeometrySource(stage_file, prims)
    check_uv_sets(compiled, source)  # binds the texcoord nodes of other UV sets to their primvars
    reads = geometry_reads(compiled.graph, compiled.spatial_nodes, compiled.evaluator.frame_bound)
    if not reads:
        return None
    primvars = sorted({r["primvar"] for r in reads if "primvar" in r})
    if "displayColor" in primvars:
        primvars.append("displayOpacity")
    source.primvars, source.transforms = primvars, any(r["kind"] in TRANSFORMS for r in reads)
    compiled.evaluator.geometry = source
    shared = None
    if any(compiled.evaluator.world_transform):
        shared = source.common_transform()
        if shared is not None:  # one matrix for the whole material: what it alone made vary folds again
            compiled.evaluator.fix_object_to_world(shared)
            compiled.refresh_spatial()
    kinds = ", ".join(sorted({r["kind"] for r in reads}))
    if source.is_sphere:
        why = ("the stage has no file to read its meshes from (in memory)" if list(prims)
               else "no USD mesh is bound")
        note = (f"the graph reads {kinds}; {why}, so the documented default mesh, the unit sphere with its "
                f"spherical UV layout, provides them (give a USD stage file to use the real meshes)")
    else:
        note = f"the graph reads {kinds}, rasterised from the bound meshes' UV layout ({', '.join(source.prims)})"
        if shared is not None:
            note += "; their one object-to-world matrix is folded into the transform nodes"
    if note not in compiled.program.notes:
        compiled.program.notes.append(note)
    return note
