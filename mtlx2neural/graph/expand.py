"""Expand a MaterialX material into the flat IR (:mod:`.ir`).

One generic mechanism serves every shading model: a node whose category has a
native torch operator (stdlib maths, texture and geometry nodes, pbrlib
closures) becomes an IR node; any other node is replaced by the library
NodeGraph that implements its nodedef, with the instance's inputs bound to the
graph's interface. standard_surface, open_pbr_surface, gltf_pbr,
UsdPreviewSurface and disney_principled all reduce this way; there is no
per-shader code.

Expansion follows connections depth first, but on an explicit stack rather
than Python's call stack (:func:`_drive`): each step that would recurse is a
generator that ``yield``s the sub-step it needs and receives its result, so a
chain of thousands of nodes expands without ``RecursionError``.
"""

from __future__ import annotations

import itertools
import os
from dataclasses import dataclass, field
from typing import Generator

import MaterialX as mx
import numpy as np

from mtlx2neural.errors import InputError, UnsupportedNodeError
from mtlx2neural.graph.ir import Const, Input, IRGraph, IRNode, Ref
from mtlx2neural.graph.library import nodegraph_implementation, with_libraries
from mtlx2neural.graph.spatial import needs_conversion
from mtlx2neural.graph.validate import check_enum_inputs
from mtlx2neural.imaging.colour import convert

# Inputs that only feed emission, which a reflectance model drops: an
# unsupported node there becomes "unconnected" (with a note) instead of an error.
EMISSION_ONLY = {"surface": {"edf"}, "surface_unlit": None}  # None: every input

# Nodes whose string/filename output is one of their inputs: folded to that constant when the graph is
# expanded, so that an image's ``file`` read through them is still a constant (checked and read at load).
# geompropvalueuniform's primvar is a per-geometry string no bake can vary: its ``default`` is used.
STRING_PASS = {"constant": "value", "dot": "in", "geompropvalueuniform": "default"}

# geomprop category -> IR category for geometric inputs.
_GEOMPROPS = {"normal", "tangent", "bitangent", "position", "texcoord", "geomcolor"}


@dataclass
class _Scope:
    """One graph being expanded: the document, a user nodegraph or a library
    nodegraph instance (then ``interface`` binds its inputs and ``library`` is True)."""

    element: mx.GraphElement
    label: str
    interface: dict[str, Input] | None = None
    library: bool = False
    uid: int = field(default_factory=itertools.count().__next__)


# A step of the expansion: a generator that yields the sub-steps it needs and returns its result.
Step = Generator["Step", object, object]


def _drive(root: Step):
    """Run the step ``root`` and every sub-step it yields on an explicit stack; return its result.

    A step's exception is thrown into the step that asked for it (so ``try``/``except``
    and ``finally`` inside steps behave as in ordinary recursion) and leaves from here
    when no step handles it.
    """
    stack, value, error = [root], None, None
    while stack:
        top = stack[-1]
        try:
            request = top.throw(error) if error is not None else top.send(value)
        except StopIteration as done:  # the step finished: hand its result to the caller
            stack.pop()
            value, error = done.value, None
            continue
        except BaseException as exc:  # the step failed: raise it in the caller
            stack.pop()
            if not stack:
                raise
            value, error = None, exc
            continue
        stack.append(request)  # the step needs a sub-step first
        value, error = None, None
    return value


TARGET_UNITS = {"distance": "meter"}
"""The unit a value with a ``unit`` attribute is converted to, per unit type: the distance unit MaterialX's
viewers give their generators (a ``tiledimage``'s ``realworldtilesize="100, 50" unit="centimeter"`` is
(1, 0.5)). Values without a ``unit`` attribute, and other unit types, are used as written."""


def _in_target_unit(elem: mx.ValueElement, value):
    """``value`` of ``elem`` converted from its ``unit`` to :data:`TARGET_UNITS` of its ``unittype``
    (by MaterialX's own linear unit converter and the library's unit definitions)."""
    unit, kind = elem.getUnit(), elem.getUnitType()
    target = TARGET_UNITS.get(kind)
    if not unit or not target or unit == target:
        return value
    typedef = elem.getDocument().getUnitTypeDef(kind)
    if typedef is None:
        return value
    try:
        return mx.LinearUnitConverter.create(typedef).convert(value, unit, target)
    except (LookupError, mx.Exception) as exc:  # an unknown unit name
        raise InputError(f"{elem.getDocument().getSourceUri() or '<in-memory document>'}: input "
                         f"'{elem.getNamePath()}' has unit '{unit}', which is not a {kind} unit of the "
                         f"MaterialX libraries ({exc}). Use one of their unit names.") from exc


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
    value = _in_target_unit(elem, value)
    if isinstance(value, (bool, int, float)):
        return (float(value),)
    if isinstance(value, (mx.Matrix33, mx.Matrix44)):  # row by row, the order of the value string
        n = value.numRows()
        return tuple(float(value[r, c]) for r in range(n) for c in range(n))
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
        self._active: set[str] = set()  # nodes being expanded (a repeat is a cycle)
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
        space = gdef.getSpace() or ""
        key = (category, index, mx_type, space)
        if key not in self._geom:
            if category not in _GEOMPROPS:
                raise UnsupportedNodeError(
                    f"{self.source}: geometric property '{name}' ({category}) is not supported.")
            self._geom[key] = self.graph.add(IRNode(
                category, f"geomprop:{name}", {"index": Const((float(index),), "integer")},
                {"out": mx_type}, f"<geomprop {name}>", attrs={"space": space} if space else {}))
        return Ref(self._geom[key])

    def resolve_input(self, scope: _Scope, inst, ndin) -> Input:
        """The IR input for instance input ``inst`` (may be None) of nodedef input ``ndin``."""
        return _drive(self._resolve(scope, inst, ndin))

    def _resolve(self, scope: _Scope, inst, ndin) -> Step:
        """Step of :meth:`resolve_input`."""
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
            return (yield self._node_output(scope, inst.getNodeName(), inst.getOutputString()))
        if inst.getOutputString() and not inst.getNodeGraphString():
            # A connection to an <output> element of the enclosing graph (or document).
            out = scope.element.getOutput(inst.getOutputString())
            if out is None:
                raise InputError(f"{self.source}: input '{inst.getNamePath()}' connects to missing output "
                                 f"'{inst.getOutputString()}'.")
            return (yield self._resolve(scope, out, None))
        if inst.getNodeGraphString():
            ng = self.doc.getNodeGraph(inst.getNodeGraphString())
            if ng is None:
                raise InputError(f"{self.source}: input '{inst.getNamePath()}' connects to missing "
                                 f"nodegraph '{inst.getNodeGraphString()}'.")
            graph_scope = yield self._document_graph(ng)
            return (yield self._graph_output(graph_scope, inst.getOutputString()))
        if inst.hasValueString() and inst.getValueString() != "":
            colorspace = inst.getActiveColorSpace() if mx_type == "filename" else ""
            value = _const_value(inst, mx_type, self.base_dir)
            if mx_type in ("color3", "color4") and isinstance(value, tuple):
                value = self._to_working_space(value, inst.getActiveColorSpace())
            return Const(value, mx_type, colorspace)
        return self._default(ndin) if ndin is not None else Const(None, mx_type)

    def _to_working_space(self, value: tuple, colorspace: str) -> tuple:
        """A colour value declared in ``colorspace``, converted into the working space (as MaterialX does)."""

        working = self.working_space or "lin_rec709"
        if not needs_conversion(colorspace, working):
            return value

        rgb = convert(np.array([value[:3]], dtype=np.float32), colorspace, working)[0]
        return tuple(float(x) for x in rgb) + tuple(value[3:])

    # -- graphs and nodes ----------------------------------------------------
    def _document_graph(self, ng: mx.NodeGraph) -> Step:
        """Step: the scope of a user nodegraph; its own inputs form its interface (resolved at document level)."""
        key = ng.getNamePath()
        if key not in self._graph_scopes:
            doc_scope = _Scope(self.doc, "")
            interface = {}
            for i in ng.getInputs():
                interface[i.getName()] = yield self._resolve(doc_scope, i, None)
            self._graph_scopes[key] = _Scope(ng, key, interface)
        return self._graph_scopes[key]

    def _graph_output(self, scope: _Scope, output: str) -> Step:
        """Step: the IR input an output of the graph of ``scope`` resolves to."""
        ng = scope.element
        outputs = ng.getOutputs()
        out = ng.getOutput(output) if output else (outputs[0] if len(outputs) == 1 else None)
        if out is None:
            raise InputError(f"{self.source}: nodegraph '{ng.getNamePath()}' has no output "
                             f"'{output}' (outputs: {[o.getName() for o in outputs]}).")
        return (yield self._resolve(scope, out, None))

    def _node_output(self, scope: _Scope, node_name: str, output: str) -> Step:
        """Step: the IR input for output ``output`` of node ``node_name`` in ``scope`` (expanded once)."""
        node = scope.element.getNode(node_name)
        if node is None:
            raise InputError(f"{self.source}: '{scope.label}' references missing node '{node_name}'.")
        key = (scope.uid, node_name)
        if key not in self._memo:
            self._memo[key] = yield self._expand_node(scope, node)
        kind, payload, nodedef = self._memo[key]
        if kind == "const":
            return payload
        out_name = output or nodedef.getActiveOutputs()[0].getName()
        if kind == "native":
            if out_name not in self.graph[payload].outputs:
                raise InputError(f"{self.source}: node '{node.getNamePath()}' has no output '{out_name}'.")
            return Ref(payload, out_name)
        return (yield self._graph_output(payload, out_name))

    def _expand_node(self, scope: _Scope, node: mx.Node) -> Step:
        """Step: ``("native", IR index, nodedef)``, ``("graph", implementation scope, nodedef)`` or
        ``("const", Const, nodedef)`` (a string pass-through, :data:`STRING_PASS`)."""
        path = f"{scope.label}/{node.getName()}" if scope.interface is not None else node.getNamePath()
        nodedef = node.getNodeDef()
        if nodedef is None:
            raise UnsupportedNodeError(
                f"{self.source}: node '{node.getNamePath()}' (category '{node.getCategory()}', type "
                f"'{node.getType()}') matches no nodedef in the MaterialX libraries. Check the node's "
                f"category, type and input types against the MaterialX specification.",
                node=node.getNamePath())
        if path in self._active:
            raise InputError(f"{self.source}: cycle through node '{path}'.")
        self._active.add(path)
        try:
            inputs = {}
            category = node.getCategory()
            lenient = EMISSION_ONLY.get(category, set()) if category in EMISSION_ONLY else set()
            for ndin in nodedef.getActiveInputs():
                name = ndin.getName()
                try:
                    inputs[name] = yield self._resolve(scope, node.getInput(name), ndin)
                except UnsupportedNodeError as exc:
                    if lenient is not None and name not in lenient:
                        raise
                    inputs[name] = Const(None, ndin.getType())
                    self.notes.append(f"emission input '{path}.{name}' dropped: {exc}")
            if not scope.library:
                # Values a library nodegraph passes on were checked on the instance that set them.
                check_enum_inputs(self.source, node.getNamePath(), nodedef, inputs)
            passed = inputs.get(STRING_PASS.get(category, ""))
            if isinstance(passed, Const) and nodedef.getType() in ("string", "filename"):
                if category == "geompropvalueuniform":
                    gp = inputs.get("geomprop")
                    self.notes.append(f"'{path}' reads the uniform primvar "
                                      f"'{gp.value if isinstance(gp, Const) else ''}', which a baked material "
                                      f"cannot vary: its default '{passed.value}' is used")
                return ("const", passed, nodedef)
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
                    f"and no nodegraph implementation to expand. Replace the node or bake it to a texture.",
                    node=node.getNamePath())
            child = _Scope(impl, f"{path}<{nodedef.getName()}>", inputs, library=True)
            return ("graph", child, nodedef)
        finally:
            self._active.discard(path)


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
                                   f"'{node.getCategory()}'; only surfacematerial is supported.",
                                   node=node.getName())
    shader_in = node.getInput("surfaceshader")
    if shader_in is None or not (shader_in.getNodeName() or shader_in.getNodeGraphString()):
        raise InputError(f"{exp.source}: material '{node.getName()}' has no surfaceshader connected. "
                         f"Connect a surface shader (e.g. standard_surface) to its 'surfaceshader' input.")
    scope = _Scope(exp.doc, "")
    root = exp.resolve_input(scope, shader_in, None)
    return exp.graph, root, exp.source, exp.notes
