"""Torch operators for MaterialX's space transforms: ``transformpoint``, ``transformvector``, ``transformnormal``.

MaterialX names three spaces (``fromspace``/``tospace``, uniform strings): ``model`` and ``object`` (the
same space: the bound geometry's own frame) and ``world``.  MaterialX's shaders transform
object/model -> world by the object-to-world matrix M, world -> object/model by its inverse, and
any other pair (same space, an empty or unknown name) not at all.  A point is transformed with w = 1 (the
translation applies), a vector with w = 0, a normal by the inverse transpose of the matrix (w = 0), and
a normal is normalised afterwards in every case, even when no matrix applies.

On its own (no geometry bound, and in the per-point node oracle, whose matrices are the identity) object
space is world space: points and vectors pass through and normals are normalised.  When the material is
bound to meshes (:func:`mtlx2neural.graph.geometry.bind_geometry`), a node transforming between an
object space and ``world`` reads, per sample, the object-to-world matrix of the prim that owns the
sample's texel (:data:`mtlx2neural.scene.uv_raster.TRANSFORM_KEY`, USD's row-vector convention:
world = [p, 1] M) through :func:`transform_rows`; for ``.mtlx`` input (the unit sphere) M is the
identity.  Such a node is spatial (evaluated per sample, never folded), unless its value only builds a
closure's shading frame, where it stays the identity like the frame it transforms (the local frame).
"""

from __future__ import annotations

import torch

from mtlx2neural.graph.ops import normalize, op

OBJECT_SPACES = ("model", "object")
WORLD = "world"
CATEGORIES = {"transformpoint": "point", "transformvector": "vector", "transformnormal": "normal"}


def object_world(fromspace: str, tospace: str) -> str | None:
    """``"to_world"`` (an object space to world), ``"to_object"`` (world to an object space) or None."""
    if fromspace in OBJECT_SPACES and tospace == WORLD:
        return "to_world"
    if fromspace == WORLD and tospace in OBJECT_SPACES:
        return "to_object"
    return None


def transform_rows(v: torch.Tensor, fromspace: str, tospace: str, kind: str, object_to_world: torch.Tensor
                   ) -> torch.Tensor:
    """``v`` [N, 3] transformed as a ``kind`` between MaterialX spaces with one object-to-world matrix per
    row: ``object_to_world`` [N, 16] (or [1, 16]), 4x4 row by row in the row-vector convention (world =
    [p, 1] M; the last row is the translation).  Object to world: points v L + t, vectors v L, normals
    v L^-T; world to object the inverse of each (points (v - t) L^-1).  Normals come back unit length;
    pairs that are not object/world pass through (normals normalised)."""
    how = object_world(fromspace or "", tospace or "")
    out = v
    if how is not None:
        m = object_to_world.to(v.dtype).reshape(-1, 4, 4)
        lin, t = m[:, :3, :3], m[:, 3, :3]
        if kind == "normal":
            a = torch.linalg.inv(lin).transpose(1, 2) if how == "to_world" else lin.transpose(1, 2)
        else:
            a = lin if how == "to_world" else torch.linalg.inv(lin)
        base = v - t if (kind == "point" and how == "to_object") else v
        out = torch.einsum("ni,nij->nj", base.expand(a.shape[0], 3) if base.shape[0] == 1 else base,
                           a.expand(base.shape[0], 3, 3) if a.shape[0] == 1 else a)
        if kind == "point" and how == "to_world":
            out = out + t
    return normalize(out) if kind == "normal" else out


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
