"""MaterialX document -> IR -> folded BSDF program (see DESIGN.md, "graph")."""

from .compile import CompiledMaterial, compile_material

__all__ = ["CompiledMaterial", "compile_material"]
