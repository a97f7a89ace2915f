"""Batched torch reference BRDF with MaterialX's hardware-shading semantics."""

from .material import ReferenceMaterial

__all__ = ["ReferenceMaterial"]
