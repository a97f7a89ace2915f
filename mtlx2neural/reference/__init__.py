"""Batched torch reference BRDF with MaterialX's hardware-shading semantics."""

from mtlx2neural.reference.material import ReferenceMaterial

__all__ = ["ReferenceMaterial"]
