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
Texture coordinates from another UV set are not kept apart, so reading one is an input error naming
the material and the sets (:func:`check_texcoord_indices` at compile time: a ``texcoord`` node with an
``index`` other than 0; :func:`check_uv_sets` when meshes are bound: a vector2 ``geompropvalue`` feeding
a texture's ``texcoord`` whose primvar is not the layout's). A vector2 primvar that *is* the layout's
reads the layout's uv directly.
"""

from __future__ import annotations

from mtlx2neural.errors import InputError
from mtlx2neural.graph.ir import Const, IRGraph, IRNode, Ref
from mtlx2neural.graph.spatial import FRAME_AXES, UV_PRIMVARS
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
    """The primvar a ``geomcolor``/``geompropvalue`` node reads (None: a UV primvar or not constant)."""
    if node.category == "geomcolor":
        return "displayColor"
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
        if n.category in ("position", "geomcolor", "geompropvalue"):
            add(i)
        if world_transform(graph, bound, i):
            fromspace, tospace = spaces(n)
            out.append({"node": n.path, "kind": n.category, "space": f"{fromspace} to {tospace}"})
        for name, v in n.inputs.items():
            if frame_read(graph, bound, i, name, v):
                add(v.node)
    return out


DEFAULT_UV_SET = "st (texcoord index 0)"


def _index(node: IRNode) -> int:
    inp = node.inputs.get("index")
    return int(inp.value[0]) if isinstance(inp, Const) and isinstance(inp.value, tuple) and inp.value else 0


def check_texcoord_indices(source: str, material: str, graph: IRGraph, nodes) -> None:
    """InputError when a live ``texcoord`` node among ``nodes`` reads a UV set other than index 0 (module
    docstring: one UV layout per material), naming the material, the sets and the node."""
    others = [graph[i] for i in nodes if graph[i].category == "texcoord" and _index(graph[i]) != 0]
    if not others:
        return
    sets = sorted({f"texcoord index {_index(n)}" for n in others})
    defaults = [graph[i].path for i in nodes if graph[i].category == "texcoord" and _index(graph[i]) == 0]
    read = f"both {DEFAULT_UV_SET} (node '{defaults[0]}') and " if defaults else ""
    raise InputError(
        f"{source}: material '{material}' reads {read}UV set {', '.join(sets)} (node '{others[0].path}'): "
        f"mtlx2neural bakes a material into one UV layout, the default set {DEFAULT_UV_SET}, and does not keep "
        f"other UV sets apart. Read the textures through texcoord index 0 (the mesh's st), or move the UV set "
        f"into st.", node=others[0].path)


def image_uv_primvars(graph: IRGraph, nodes) -> list[tuple[int, str]]:
    """(node, primvar) of every vector2 ``geompropvalue`` among ``nodes`` whose value reaches a node's
    ``texcoord`` input (through any maths) and whose primvar is not one of the default UV names."""
    live = set(nodes)
    seen, stack = set(), [graph[i].inputs["texcoord"].node for i in nodes
                          if isinstance(graph[i].inputs.get("texcoord"), Ref)]
    found = []
    while stack:
        i = stack.pop()
        if i in seen or i not in live:
            continue
        seen.add(i)
        n = graph[i]
        gp = n.inputs.get("geomprop")
        if n.category == "geompropvalue" and n.type == "vector2" and isinstance(gp, Const) \
                and isinstance(gp.value, str) and gp.value not in UV_PRIMVARS:
            found.append((i, gp.value))
        stack.extend(v.node for v in n.inputs.values() if isinstance(v, Ref))
    return sorted(found)


def check_uv_sets(compiled, source) -> None:
    """Check the UV sets ``compiled``'s textures read against the layout of the bound meshes
    (``source``, a :class:`~mtlx2neural.scene.uv_raster.GeometrySource`; module docstring): a texture
    coordinate primvar that is the layout's set reads the layout's uv (``attrs["layout_uv"]``); any other
    is an InputError naming the material, the two sets and the node."""
    graph = compiled.graph
    reads = image_uv_primvars(graph, compiled.spatial_nodes)
    if not reads:
        return
    layout = sorted({v for v in source.uv_sets().values() if v})
    for i, primvar in reads:
        if primvar in layout:
            graph[i].attrs["layout_uv"] = "1"
            continue
        where = (f"the bound meshes' UV layout, {' / '.join(layout)}" if layout else
                 "the unit sphere's UV layout (no mesh: it has no primvars)" if source.is_sphere else
                 "the bound meshes' UV layout (they have no UVs)")
        raise InputError(
            f"{compiled.source}: material '{compiled.name}' reads its texture coordinates from the primvar "
            f"'{primvar}' (node '{graph[i].path}'), another UV set than {where}: mtlx2neural bakes a material "
            f"into one UV layout and does not keep UV sets apart. Read the textures through that set (texcoord "
            f"index 0), or make '{primvar}' the meshes' st.", node=graph[i].path)


def bind_geometry(compiled, stage_file: str | None = None, prims=()) -> str | None:
    """Give ``compiled``'s evaluator the geometry its graph reads: the meshes ``prims`` of the USD stage
    ``stage_file``, or the unit sphere when there are none (``.mtlx`` input). Returns a one-line note
    (also added to the program's notes), or None when the graph reads no geometry (nothing is bound).
    InputError when a texture reads its coordinates from another UV set than the layout's (:func:`check_uv_sets`)."""
    reads = geometry_reads(compiled.graph, compiled.spatial_nodes, compiled.evaluator.frame_bound)
    if not reads:
        return None
    primvars = sorted({r["primvar"] for r in reads if "primvar" in r})
    if "displayColor" in primvars:
        primvars.append("displayOpacity")
    source = GeometrySource(stage_file, prims, primvars, transforms=any(r["kind"] in TRANSFORMS for r in reads))
    check_uv_sets(compiled, source)
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
