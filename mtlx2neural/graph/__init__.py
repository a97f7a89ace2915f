"""MaterialX document -> IR -> folded BSDF program (see docs/ARCHITECTURE.md, "graph")."""

from mtlx2neural.graph.compile import CompiledMaterial, compile_material

__all__ = ["CompiledMaterial", "compile_material"]
