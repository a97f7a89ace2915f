"""Errors of the MaterialX Slang oracle (:mod:`mtlx2neural.oracle.runner`).

They live in their own module so that shader generation (:mod:`mtlx2neural.oracle.source`) and texture
reading (:mod:`mtlx2neural.oracle.textures`) can raise them without importing the evaluator;
:mod:`mtlx2neural.oracle.runner` re-exports both.
"""

from __future__ import annotations

from mtlx2neural.errors import Mtlx2NeuralError

__all__ = ["OracleError", "OracleUnsupported"]


class OracleError(Mtlx2NeuralError):
    """The oracle cannot run here, or MaterialX generation or Slang compilation of its shader failed."""


class OracleUnsupported(OracleError):
    """The material uses something the oracle cannot evaluate."""
