"""Evaluate IR values: constant folding at compile time, the spatial sub-graph per call.

A node is *spatial* when it is a spatial source (:mod:`.sources`) or depends on
one; everything else that is not a closure is folded once into a ``[1, C]``
constant. At run time only the spatial nodes that the live BSDF program needs
are evaluated, in topological order, for a batch of texture coordinates.
"""

from __future__ import annotations

import torch

from mtlx2neural.errors import InputError
from mtlx2neural.graph import blackbody, compositing, noise, ramps, transforms  # noqa: F401  (register operators)
from mtlx2neural.graph.ir import CHANNELS, Const, Input, IRGraph, Ref
from mtlx2neural.graph.ops import OPS
from mtlx2neural.graph.spatial import FRAME_AXES, SPATIAL, eval_source


def const_tensor(c: Const, device=None, dtype=torch.float32):
    """Torch form of a constant: ``[1, C]`` tensor, str, or None (unconnected closure)."""
    if c.value is None:
        if c.type in CHANNELS:
            return torch.zeros(1, CHANNELS[c.type], dtype=dtype, device=device)
        return None
    if isinstance(c.value, str):
        return c.value
    return torch.tensor([list(c.value)], dtype=dtype, device=device)


class GraphEvaluator:
    """Folds constants of ``graph`` and evaluates its spatial part on demand."""

    def __init__(self, graph: IRGraph, source: str, device="cpu", dtype=torch.float32):
        self.graph = graph
        self.source = source
        self.device = torch.device(device)
        self.dtype = dtype
        self.spatial = [False] * len(graph.nodes)
        self.const: dict[tuple[int, str], object] = {}
        self._classify()
        self._fold()

    # -- compile time ---------------------------------------------------------------
    def _classify(self):
        for i, node in enumerate(self.graph.nodes):
            self.spatial[i] = node.category in SPATIAL or any(
                isinstance(v, Ref) and self.spatial[v.node] for v in node.inputs.values())

    def _fold(self):
        for i, node in enumerate(self.graph.nodes):
            if self.spatial[i] or node.is_closure():
                continue
            if node.category in FRAME_AXES:
                self.const[(i, "out")] = torch.tensor([FRAME_AXES[node.category]], dtype=self.dtype,
                                                      device=self.device)
                continue
            args = {k: self.value(v, {}) for k, v in node.inputs.items()}
            self._store(i, self._run_op(i, args), self.const)

    def _run_op(self, i, args):
        node = self.graph[i]
        try:
            return OPS[node.category](args, node)
        except KeyError as exc:
            raise InputError(f"{self.source}: node '{node.path}' ({node.nodedef}) is missing input {exc}.") from exc

    def _store(self, i, result, table):
        node = self.graph[i]
        if isinstance(result, dict):
            for k, v in result.items():
                table[(i, k)] = v
        else:
            table[(i, next(iter(node.outputs)))] = result

    def is_constant(self, inp: Input) -> bool:
        return isinstance(inp, Const) or not self.spatial[inp.node]

    def value(self, inp: Input, env: dict):
        """Value of an input: a constant, a folded node output, or a spatial value from ``env``."""
        if isinstance(inp, Const):
            return const_tensor(inp, self.device, self.dtype)
        key = (inp.node, inp.output)
        if key in self.const:
            return self.const[key]
        return env[key]

    # -- run time -------------------------------------------------------------------
    def spatial_closure(self, inputs: list[Input]) -> list[int]:
        """Spatial node indices needed to evaluate ``inputs``, in topological order."""
        needed: set[int] = set()
        stack = [i.node for i in inputs if isinstance(i, Ref) and self.spatial[i.node]]
        while stack:
            i = stack.pop()
            if i in needed:
                continue
            needed.add(i)
            stack.extend(v.node for v in self.graph[i].inputs.values()
                         if isinstance(v, Ref) and self.spatial[v.node])
        return sorted(needed)

    def run(self, nodes: list[int], uv: torch.Tensor, position: torch.Tensor | None = None) -> dict:
        """Evaluate spatial ``nodes`` (from :meth:`spatial_closure`) at ``uv`` [N,2]; ``position``
        [N,3] (optional) is the surface point that ``position`` nodes read (default (u, v, 0))."""
        env: dict = {}
        for i in nodes:
            node = self.graph[i]
            args = {k: self.value(v, env) for k, v in node.inputs.items()}
            if node.category in SPATIAL:
                env[(i, "out")] = eval_source(node, args, uv, position)
            else:
                self._store(i, self._run_op(i, args), env)
        return env
