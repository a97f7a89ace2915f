"""Torch operators for MaterialX's space transforms: ``transformpoint``, ``transformvector``, ``transformnormal``.

MaterialX names three spaces (``fromspace``/``tospace``, uniform strings): ``model`` and ``object`` (the
same space: the bound geometry's own frame) and ``world``.  MaterialX's shaders transform
object/model -> world by the object-to-world matrix M, world -> object/model by its inverse, and
any other pair (same space, an empty or unknown name) not at all.  A point is transformed with w = 1 (the
translation applies), a vector with w = 0, a normal by the inverse transpose of the matrix (w = 0), and
a normal is normalised afterwards in every case, even when no matrix applies.

Here object space is world space (M is the identity): the material is evaluated on its own, over the
flat stand-in surface that ``position`` describes (:mod:`mtlx2neural.graph.spatial`), exactly as the
per-point node oracle sets MaterialX's matrices.  So points and vectors pass through and normals are
normalised; :func:`space_matrix` takes a real M (a bound prim's transform, a later step) and gives the
matrix MaterialX would use.
"""

from __future__ import annotations

import torch

from mtlx2neural.graph.ops import normalize, op

OBJECT_SPACES = ("model", "object")
WORLD = "world"


def space_matrix(fromspace: str, tospace: str, kind: str, object_to_world: torch.Tensor | None = None):
    """The 4x4 matrix (column vectors: x' = A x) MaterialX applies for ``kind`` ("point", "vector" or
    "normal") from ``fromspace`` to ``tospace``, or None when none applies.  ``object_to_world``: M, 4x4
    (default identity: object space is world space)."""
    if fromspace in OBJECT_SPACES and tospace == WORLD:
        to_world = True
    elif fromspace == WORLD and tospace in OBJECT_SPACES:
        to_world = False
    else:
        return None
    m = torch.eye(4) if object_to_world is None else object_to_world
    if kind == "normal":  # the inverse transpose of the matrix a vector would take
        return torch.linalg.inv(m).transpose(0, 1) if to_world else m.transpose(0, 1)
    return m if to_world else torch.linalg.inv(m)


def transform(v: torch.Tensor, fromspace: str, tospace: str, kind: str,
              object_to_world: torch.Tensor | None = None) -> torch.Tensor:
    """``v`` [B, 3] transformed as a ``kind`` ("point", "vector", "normal") between MaterialX spaces (see
    the module docstring); normals come back unit length."""
    m = space_matrix(fromspace or "", tospace or "", kind, object_to_world)
    out = v
    if m is not None:
        m = m.to(v.dtype).to(v.device)
        w = 1.0 if kind == "point" else 0.0
        out = v @ m[:3, :3].transpose(0, 1) + w * m[:3, 3]
    return normalize(out) if kind == "normal" else out


op("transformpoint")(lambda a, n: transform(a["in"], a.get("fromspace", ""), a.get("tospace", ""), "point"))
op("transformvector")(lambda a, n: transform(a["in"], a.get("fromspace", ""), a.get("tospace", ""), "vector"))
op("transformnormal")(lambda a, n: transform(a["in"], a.get("fromspace", ""), a.get("tospace", ""), "normal"))
