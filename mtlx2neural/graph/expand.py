"""Expand a MaterialX material into the flat IR (:mod:`.ir`).

One generic mechanism serves every shading model: a node whose category has a
native torch operator (stdlib maths, texture and geometry nodes, pbrlib
closures) becomes an IR node; any other node is replaced by the library
NodeGraph that implements its nodedef, with the instance's inputs bound to the
graph's interface. standard_surface, open_pbr_surface, gltf_pbr,
UsdPreviewSurface and disney_principled all reduce this way; there is no
per-shader code.
"""

from __future__ import annotations

import itertools
import os
from dataclasses import dataclass, field

import MaterialX as mx

from ..errors import InputError, UnsupportedNodeError
from .ir import Const, Input, IRGraph, IRNode, Ref
from .library import nodegraph_implementation, with_libraries

# Inputs that only feed emission, which a reflectance model drops: an
# unsupported node there becomes "unconnected" (with a note) instead of an error.
EMISSION_ONLY = {"surface": {"edf"}, "surface_unlit": None}  # None: every input

# geomprop category -> IR category for geometric inputs.
_GEOMPROPS = {"normal", "tangent", "bitangent", "position", "texcoord", "geomcolor"}


@dataclass
class _Scope:
    """One graph being expanded: the document, a user nodegraph or a library
    nodegraph instance (then ``interface`` binds its inputs)."""

    element: mx.GraphElement
    label: str
    interface: dict[str, Input] | None = None
    uid: int = field(default_factory=itertools.count().__next__)


def _const_value(elem: mx.ValueElement, mx_type: str, base_dir: str):
    """Python value of a MaterialX value element, in IR constant form."""
    if mx_type == "filename":
        path = elem.getResolvedValueString()
        if path and not os.path.isabs(path) and base_dir:
            path = os.path.normpath(os.path.join(base_dir, path))
        return path
    value = elem.getValue()
    if mx_type == "string" or isinstance(value, str):
        return value
    if isinstance(value, (bool, int, float)):
        return (float(value),)
    if hasattr(value, "asTuple"):
        value = value.asTuple()
    return tuple(float(x) for x in value)


class Expander:
    """Expands one material of one document; see :func:`expand_material`."""

    def __init__(self, document: mx.Document, native: set[str]):
        self.source = document.getSourceUri() or "<in-memory document>"
        self.doc = with_libraries(document)
        self.base_dir = os.path.dirname(self.source) if document.getSourceUri() else ""
        self.native = native
        self.graph = IRGraph()
        self._memo: dict[tuple[int, str], object] = {}
        self._geom: dict[tuple, int] = {}
        self._stack: list[str] = []
        self._graph_scopes: dict[str, _Scope] = {}
        self.notes: list[str] = []
        # The working colour space; as in MaterialX's generators, texture colour spaces are
        # converted only when the document declares one.
        self.working_space = document.getColorSpace()

    # -- inputs ---------------------------------------------------------------
    def _default(self, ndin: mx.Input) -> Input:
        geomprop = ndin.getDefaultGeomPropString()
        if geomprop:
            return self._geomprop(geomprop, ndin.getType())
        if ndin.hasValueString() and ndin.getValueString() != "":
            return Const(_const_value(ndin, ndin.getType(), self.base_dir), ndin.getType())
        return Const(None, ndin.getType())

    def _geomprop(self, name: str, mx_type: str) -> Input:
        gdef = self.doc.getGeomPropDef(name)
        if gdef is None:
            raise InputError(f"{self.source}: unknown default geometric property '{name}'.")
        category = gdef.getGeomProp()
        index = gdef.getIndex() if category == "texcoord" else 0
        key = (category, index, mx_type)
        if key not in self._geom:
            if category not in _GEOMPROPS:
                raise UnsupportedNodeError(
                    f"{self.source}: geometric property '{name}' ({category}) is not supported.")
            self._geom[key] = self.graph.add(IRNode(
                category, f"geomprop:{name}", {"index": Const((float(index),), "integer")},
                {"out": mx_type}, f"<geomprop {name}>"))
        return Ref(self._geom[key])

    def resolve_input(self, scope: _Scope, inst, ndin) -> Input:
        """The IR input for instance input ``inst`` (may be None) of nodedef input ``ndin``."""
        if inst is None:
            return self._default(ndin) if ndin is not None else Const(None, "float")
        mx_type = inst.getType()
        if inst.getInterfaceName():
            if scope.interface is None:
                raise InputError(f"{self.source}: input '{inst.getNamePath()}' uses interfacename "
                                 f"'{inst.getInterfaceName()}' outside a nodegraph with an interface.")
            bound = scope.interface.get(inst.getInterfaceName())
            if bound is None:
                raise InputError(f"{self.source}: interface input '{inst.getInterfaceName()}' "
                                 f"referenced by '{inst.getNamePath()}' is not declared.")
            return bound
        if inst.getNodeName():
            return self.node_output(scope, inst.getNodeName(), inst.getOutputString())
        if inst.getOutputString() and not inst.getNodeGraphString():
            # A connection to an <output> element of the enclosing graph (or document).
            out = scope.element.getOutput(inst.getOutputString())
            if out is None:
                raise InputError(f"{self.source}: input '{inst.getNamePath()}' connects to missing output "
                                 f"'{inst.getOutputString()}'.")
            return self.resolve_input(scope, out, None)
        if inst.getNodeGraphString():
            ng = self.doc.getNodeGraph(inst.getNodeGraphString())
            if ng is None:
                raise InputError(f"{self.source}: input '{inst.getNamePath()}' connects to missing "
                                 f"nodegraph '{inst.getNodeGraphString()}'.")
            return self.graph_output(self._document_graph(ng), inst.getOutputString())
        if inst.hasValueString() and inst.getValueString() != "":
            colorspace = inst.getActiveColorSpace() if mx_type == "filename" else ""
            value = _const_value(inst, mx_type, self.base_dir)
            if mx_type in ("color3", "color4") and isinstance(value, tuple):
                value = self._to_working_space(value, inst.getActiveColorSpace())
            return Const(value, mx_type, colorspace)
        return self._default(ndin) if ndin is not None else Const(None, mx_type)

    def _to_working_space(self, value: tuple, colorspace: str) -> tuple:
        """A colour value declared in ``colorspace``, converted into the working space (as MaterialX does)."""
        from .sources import needs_conversion
        from ..textures.colour import convert

        working = self.working_space or "lin_rec709"
        if not needs_conversion(colorspace, working):
            return value
        import numpy as np

        rgb = convert(np.array([value[:3]], dtype=np.float32), colorspace, working)[0]
        return tuple(float(x) for x in rgb) + tuple(value[3:])

    # -- graphs and nodes ----------------------------------------------------
    def _document_graph(self, ng: mx.NodeGraph) -> _Scope:
        """Scope of a user nodegraph; its own inputs form its interface (resolved at document level)."""
        key = ng.getNamePath()
        if key not in self._graph_scopes:
            doc_scope = _Scope(self.doc, "")
            interface = {i.getName(): self.resolve_input(doc_scope, i, None) for i in ng.getInputs()}
            self._graph_scopes[key] = _Scope(ng, key, interface)
        return self._graph_scopes[key]

    def graph_output(self, scope: _Scope, output: str) -> Input:
        ng = scope.element
        outputs = ng.getOutputs()
        out = ng.getOutput(output) if output else (outputs[0] if len(outputs) == 1 else None)
        if out is None:
            raise InputError(f"{self.source}: nodegraph '{ng.getNamePath()}' has no output "
                             f"'{output}' (outputs: {[o.getName() for o in outputs]}).")
        return self.resolve_input(scope, out, None)

    def node_output(self, scope: _Scope, node_name: str, output: str) -> Input:
        node = scope.element.getNode(node_name)
        if node is None:
            raise InputError(f"{self.source}: '{scope.label}' references missing node '{node_name}'.")
        key = (scope.uid, node_name)
        if key not in self._memo:
            self._memo[key] = self._expand_node(scope, node)
        kind, payload, nodedef = self._memo[key]
        out_name = output or nodedef.getActiveOutputs()[0].getName()
        if kind == "native":
            if out_name not in self.graph[payload].outputs:
                raise InputError(f"{self.source}: node '{node.getNamePath()}' has no output '{out_name}'.")
            return Ref(payload, out_name)
        return self.graph_output(payload, out_name)

    def _expand_node(self, scope: _Scope, node: mx.Node):
        path = f"{scope.label}/{node.getName()}" if scope.interface is not None else node.getNamePath()
        nodedef = node.getNodeDef()
        if nodedef is None:
            raise UnsupportedNodeError(
                f"{self.source}: node '{node.getNamePath()}' (category '{node.getCategory()}', type "
                f"'{node.getType()}') matches no nodedef in the MaterialX libraries. Check the node's "
                f"category, type and input types against the MaterialX specification.")
        if path in self._stack:
            raise InputError(f"{self.source}: cycle through node '{path}'.")
        self._stack.append(path)
        try:
            inputs = {}
            category = node.getCategory()
            lenient = EMISSION_ONLY.get(category, set()) if category in EMISSION_ONLY else set()
            for ndin in nodedef.getActiveInputs():
                name = ndin.getName()
                try:
                    inputs[name] = self.resolve_input(scope, node.getInput(name), ndin)
                except UnsupportedNodeError as exc:
                    if lenient is not None and name not in lenient:
                        raise
                    inputs[name] = Const(None, ndin.getType())
                    self.notes.append(f"emission input '{path}.{name}' dropped: {exc}")
            if category in self.native:
                attrs = {}
                file_in = inputs.get("file")
                if isinstance(file_in, Const) and file_in.type == "filename":
                    attrs["colorspace"] = file_in.colorspace
                    attrs["working_space"] = self.working_space
                idx = self.graph.add(IRNode(
                    category, nodedef.getName(), inputs,
                    {o.getName(): o.getType() for o in nodedef.getActiveOutputs()}, path, attrs))
                return ("native", idx, nodedef)
            impl = nodegraph_implementation(self.doc, nodedef)
            if impl is None:
                raise UnsupportedNodeError(
                    f"{self.source}: node '{node.getNamePath()}' uses nodedef '{nodedef.getName()}' "
                    f"(category '{category}'), which mtlx2neural cannot evaluate: it has no torch operator "
                    f"and no nodegraph implementation to expand. Replace the node or bake it to a texture.")
            child = _Scope(impl, f"{path}<{nodedef.getName()}>", inputs)
            return ("graph", child, nodedef)
        finally:
            self._stack.pop()


def find_material_node(document: mx.Document, material: str | None) -> mx.Node:
    """The ``surfacematerial`` node named ``material`` (or the only one)."""
    source = document.getSourceUri() or "<in-memory document>"
    mats = [n for n in document.getMaterialNodes() if n.getType() == "material"]
    if material is None:
        if len(mats) != 1:
            raise InputError(f"{source}: holds {len(mats)} materials "
                             f"({', '.join(m.getName() for m in mats)}); name one with --material.")
        return mats[0]
    for m in mats:
        if m.getName() == material or m.getNamePath() == material:
            return m
    raise InputError(f"{source}: no material named '{material}'. "
                     f"Available: {', '.join(m.getName() for m in mats) or 'none'}.")


def expand_material(document: mx.Document, material: str | None, native: set[str]):
    """Expand ``material`` into an IR graph.

    Returns the graph, the IR input feeding the material's ``surfaceshader``,
    the source label used in messages, and notes on dropped emission inputs.
    """
    exp = Expander(document, native)
    node = find_material_node(exp.doc, material)
    if node.getCategory() != "surfacematerial":
        raise UnsupportedNodeError(f"{exp.source}: material '{node.getName()}' is a "
                                   f"'{node.getCategory()}'; only surfacematerial is supported.")
    shader_in = node.getInput("surfaceshader")
    if shader_in is None or not (shader_in.getNodeName() or shader_in.getNodeGraphString()):
        raise InputError(f"{exp.source}: material '{node.getName()}' has no surfaceshader connected. "
                         f"Connect a surface shader (e.g. standard_surface) to its 'surfaceshader' input.")
    scope = _Scope(exp.doc, "")
    root = exp.resolve_input(scope, shader_in, None)
    return exp.graph, root, exp.source, exp.notes
