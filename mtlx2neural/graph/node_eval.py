"""Evaluate one node output of a MaterialX document at many surface points (the torch side of the per-point
node oracle, :func:`mtlx2neural.oracle.points.mtlx_node_eval`).

The output is expanded with the same :class:`~mtlx2neural.graph.expand.Expander` as a material, so library
nodegraphs, folding and the torch operators are exactly those a material uses.
"""

from __future__ import annotations

from dataclasses import dataclass

import MaterialX as mx
import torch

from mtlx2neural.errors import InputError
from mtlx2neural.graph.compile import NATIVE
from mtlx2neural.graph.evaluator import GraphEvaluator
from mtlx2neural.graph.expand import Expander, _drive, _Scope
from mtlx2neural.graph.ir import CHANNELS, Const, Input, IRGraph
from mtlx2neural.graph.ops import Application, bake_application

__all__ = ["CompiledOutput", "compile_output"]


@dataclass
class CompiledOutput:
    """A compiled node output: call it with ``uv`` [N,2] (optionally ``position`` and ``normal`` [N,3])."""

    graph: IRGraph
    evaluator: GraphEvaluator
    input: Input
    type: str

    def __call__(self, uv: torch.Tensor, position: torch.Tensor | None = None,
                 normal: torch.Tensor | None = None) -> torch.Tensor:
        """Value [N, C] (C the type's channel count) at texture coordinates ``uv`` [N,2] (MaterialX's
        convention), surface points ``position`` [N,3] (default (u, v, 0); units of the document) and
        unit surface normals ``normal`` [N,3] (default +z), each used in object and world space alike,
        as the oracle's probe (no transform). ``normal`` reaches the ``normal`` nodes read as geometry
        (:mod:`mtlx2neural.graph.geometry`), not a closure's shading frame."""
        ev = self.evaluator
        uv = uv.to(ev.device, ev.dtype)
        if position is not None:
            position = position.to(ev.device, ev.dtype)
        geometry = None
        if normal is not None:
            normal = normal.to(ev.device, ev.dtype)
            geometry = {"normal:object": normal, "normal:world": normal}
        nodes = ev.spatial_closure([self.input])
        env = ev.run(nodes, uv, position, geometry)
        value = ev.value(self.input, env)
        return value.expand(uv.shape[0], CHANNELS[self.type])


def compile_output(document: mx.Document, target: str, output: str | None = None,
                   device="cpu", application: Application | None = None) -> CompiledOutput:
    """Compile output ``output`` of ``target`` in ``document`` (without libraries): ``target`` names a
    top-level node (``output`` for a multi-output node) or a nodegraph (``output`` names its output
    unless it has only one). ``time``/``frame`` nodes fold to ``application`` (None: frame 1 at 24 fps,
    :class:`~mtlx2neural.graph.ops.Application`)."""
    exp = Expander(document, NATIVE)
    scope = _Scope(exp.doc, "")
    elem = exp.doc.getChild(target)
    if elem is not None and elem.isA(mx.NodeGraph):
        graph_scope = _drive(exp._document_graph(elem))
        inp = _drive(exp._graph_output(graph_scope, output or ""))
    elif elem is not None and elem.isA(mx.Node):
        inp = _drive(exp._node_output(scope, target, output or ""))
    else:
        raise InputError(f"{exp.source}: no top-level node or nodegraph named '{target}'.")
    mx_type = inp.type if isinstance(inp, Const) else exp.graph.output_type(inp)
    bake_application(exp.graph, application)
    ev = GraphEvaluator(exp.graph, exp.source, device=device)
    return CompiledOutput(exp.graph, ev, inp, mx_type)
