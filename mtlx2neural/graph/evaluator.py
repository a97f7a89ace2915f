"""Evaluate IR values: constant folding at compile time, the spatial sub-graph per call.

A node is *spatial* when it is a spatial source (:mod:`.sources`) or depends on
one; everything else that is not a closure is folded once into a ``[1, C]``
constant. At run time only the spatial nodes that the live BSDF program needs
are evaluated, in topological order, for a batch of texture coordinates.

Geometry (:mod:`mtlx2neural.graph.geometry`): a node that reads ``normal``/``tangent``/``bitangent``
for anything but building a closure's shading frame is spatial too, and so is a ``transform*`` node
between an object space and world (it reads the bound prims' object-to-world matrix per sample). When the evaluator has a
``geometry`` source (:func:`~mtlx2neural.graph.geometry.bind_geometry`), ``run`` samples its maps
(bilinear, at the source's current grid) at the uv of the batch, only when the nodes run read geometry.
"""

from __future__ import annotations

import torch

from mtlx2neural.errors import InputError
from mtlx2neural.graph import (  # noqa: F401  (register operators)
    blackbody,
    compositing,
    flake,
    heightfield,
    hextile,
    matrix,
    noise,
    ramps,
    transforms,
)
from mtlx2neural.graph.geometry import (
    GEOMETRIC,
    frame_bound,
    frame_read,
    node_space,
    primvar_of,
    spaces,
    world_transform,
)
from mtlx2neural.graph.ir import CHANNELS, Const, Input, IRGraph, Ref
from mtlx2neural.graph.ops import OPS
from mtlx2neural.graph.spatial import FRAME_AXES, SPATIAL, eval_source
from mtlx2neural.graph.transforms import CATEGORIES as TRANSFORMS
from mtlx2neural.graph.transforms import transform_rows
from mtlx2neural.scene.uv_raster import TRANSFORM_KEY


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
        self.geometry = None
        """A :class:`~mtlx2neural.scene.uv_raster.GeometrySource` the geometric nodes read, or None
        (then position is (u, v, 0), the frame its axes, primvars their defaults)."""
        self._geo_keys: dict[tuple, list[str]] = {}
        self.frame_bound = frame_bound(graph)
        self.object_world = [world_transform(graph, self.frame_bound, i) for i in range(len(graph.nodes))]
        """Per node: a ``transform*`` between object and world (not only a shading frame)."""
        self.world_transform = list(self.object_world)
        """Per node: such a transform that reads the prims' matrix per sample (spatial); none once
        :meth:`fix_object_to_world` gave one matrix for the material."""
        self.object_to_world: torch.Tensor | None = None
        """[1, 16] the material's one object-to-world matrix (row-vector convention), or None."""
        self._classify()
        self._fold()

    # -- compile time ---------------------------------------------------------------
    def _classify(self):
        for i, node in enumerate(self.graph.nodes):
            self.spatial[i] = node.category in SPATIAL or self.world_transform[i] or any(
                isinstance(v, Ref) and (self.spatial[v.node] or self._geo_frame(i, k, v))
                for k, v in node.inputs.items())

    def _geo_frame(self, consumer: int, name: str, inp) -> bool:
        """Whether input ``name`` of node ``consumer`` is a frame node read as geometry (not the shading frame)."""
        return frame_read(self.graph, self.frame_bound, consumer, name, inp)

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

    def fix_object_to_world(self, object_to_world: torch.Tensor) -> None:
        """Give the object/world ``transform*`` nodes one matrix for the whole material (``object_to_world`` [1, 16]
        or [16], row-vector convention: all bound prims share it, or the sphere's identity): they stop
        being spatial, and what only they made vary folds to constants again (classification and
        folding are redone; :meth:`CompiledMaterial.refresh_spatial` updates the live spatial nodes)."""
        self.object_to_world = object_to_world.reshape(1, 16).to(self.device, self.dtype)
        self.world_transform = [False] * len(self.graph.nodes)
        self.spatial = [False] * len(self.graph.nodes)
        self.const = {}
        self._geo_keys = {}
        self._classify()
        self._fold()

    def _run_op(self, i, args, geometry: dict | None = None):
        node = self.graph[i]
        if self.object_world[i]:  # the prims' matrix: per sample, or the material's one
            matrix = (geometry or {}).get(TRANSFORM_KEY) if self.world_transform[i] else self.object_to_world
            if matrix is not None:
                return transform_rows(args["in"], *spaces(node), TRANSFORMS[node.category], matrix)
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

    def geometry_keys(self, nodes: list[int]) -> list[str]:
        """The geometry map keys (``position:object``, ``primvar:displayColor``...) ``nodes`` read."""
        key = tuple(nodes)
        if key not in self._geo_keys:
            keys = []
            for i in nodes:
                node = self.graph[i]
                reads = [node] if node.category in GEOMETRIC or primvar_of(node) else []
                if self.world_transform[i]:
                    keys.append(TRANSFORM_KEY)
                reads += [self.graph[v.node] for k, v in node.inputs.items() if self._geo_frame(i, k, v)]
                for n in reads:
                    pv = primvar_of(n) if n.category in ("geomcolor", "geompropvalue", "texcoord") else None
                    if pv:
                        keys += [f"primvar:{pv}"] + (["primvar:displayOpacity"] if pv == "displayColor" else [])
                    elif n.category not in ("geomcolor", "geompropvalue", "texcoord"):
                        keys.append(f"{n.category}:{node_space(n)}")
            self._geo_keys[key] = sorted(set(keys))
        return self._geo_keys[key]

    def run(self, nodes: list[int], uv: torch.Tensor, position: torch.Tensor | None = None,
            geometry: dict | None = None) -> dict:
        """Evaluate spatial ``nodes`` (from :meth:`spatial_closure`) at ``uv`` [N,2].

        ``geometry``: ``{key: [N, C]}`` per-sample geometry (keys of
        :class:`~mtlx2neural.scene.uv_raster.GeometryMaps`); default: the evaluator's ``geometry``
        source sampled at ``uv`` when ``nodes`` read any, else none. ``position`` [N,3] (optional, the
        per-point oracle's): the surface point every ``position`` node reads (default (u, v, 0))."""
        if heightfield.wants_uv_grad(self.graph, nodes):  # heighttonormal: derivatives with respect to uv
            return heightfield.run_differentiable(self.run, nodes, uv, position, geometry)
        if position is not None:
            geometry = {**(geometry or {}), "position:object": position, "position:world": position}
        elif geometry is None and self.geometry is not None:
            keys = self.geometry_keys(nodes)
            if keys:
                geometry = self.geometry.current().sample(uv, keys)
        env: dict = {}
        n_rows = uv.shape[0]
        for i in nodes:
            node = self.graph[i]
            args = {k: self._frame_value(v, n_rows, geometry) if self._geo_frame(i, k, v) else self.value(v, env)
                    for k, v in node.inputs.items()}
            if node.category in SPATIAL:
                env[(i, "out")] = eval_source(node, args, uv, geometry)
            else:
                self._store(i, self._run_op(i, args, geometry), env)
        return env

    def _frame_value(self, inp: Ref, n: int, geometry: dict | None) -> torch.Tensor:
        """A frame node read as geometry: its map's value per row, or its axis without geometry."""
        node = self.graph[inp.node]
        got = (geometry or {}).get(f"{node.category}:{node_space(node)}")
        if got is not None:
            return got
        return torch.tensor([FRAME_AXES[node.category]], dtype=self.dtype, device=self.device).expand(n, 3)
