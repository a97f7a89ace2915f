"""The compiler's intermediate representation: a flat DAG of typed operators.

Every MaterialX node that survives expansion becomes one :class:`IRNode` whose
``category`` names a torch operator in :mod:`mtlx2neural.graph.ops` (stdlib maths,
texture lookups, geometric inputs) or a pbrlib closure in
:mod:`mtlx2neural.reference.closures`. Inputs are either constants or references
to another node's named output. Library nodegraphs are gone after expansion.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Union

# MaterialX type name -> number of float channels in the torch representation.
CHANNELS = {
    "float": 1, "integer": 1, "boolean": 1,
    "vector2": 2, "vector3": 3, "vector4": 4,
    "color3": 3, "color4": 4,
    "matrix33": 9, "matrix44": 16,
}

CLOSURE_TYPES = {"BSDF", "EDF", "VDF", "surfaceshader", "displacementshader", "volumeshader", "material", "lightshader"}


@dataclass(frozen=True)
class Const:
    """A constant input: a Python float/tuple (numeric types) or a str (strings, filenames)."""

    value: Any
    type: str
    colorspace: str = ""  # for filename inputs: the colour space MaterialX declares for the file


@dataclass(frozen=True)
class Ref:
    """A reference to output ``output`` of IR node ``node`` (an index into ``IRGraph.nodes``)."""

    node: int
    output: str = "out"


Input = Union[Const, Ref]


@dataclass
class IRNode:
    """One operator instance.

    ``category``: MaterialX node category (``add``, ``dielectric_bsdf``, ``image``...).
    ``nodedef``: the MaterialX nodedef name it came from (for messages).
    ``outputs``: output name -> MaterialX type.
    ``path``: the MaterialX element path of the originating node, with the chain of
    library nodegraphs it was expanded through, for messages and ``describe()``.
    """

    category: str
    nodedef: str
    inputs: dict[str, Input]
    outputs: dict[str, str]
    path: str
    attrs: dict[str, str] = field(default_factory=dict)

    @property
    def type(self) -> str:
        return next(iter(self.outputs.values()))

    def is_closure(self) -> bool:
        return self.type in CLOSURE_TYPES


@dataclass
class IRGraph:
    """Nodes in topological order (every Ref points to an earlier node)."""

    nodes: list[IRNode] = field(default_factory=list)

    def add(self, node: IRNode) -> int:
        self.nodes.append(node)
        return len(self.nodes) - 1

    def __getitem__(self, i: int) -> IRNode:
        return self.nodes[i]

    def output_type(self, ref: Ref) -> str:
        return self.nodes[ref.node].outputs[ref.output]
