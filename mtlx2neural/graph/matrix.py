"""Torch operators for MaterialX's matrix33/matrix44 nodes.

Representation: a matrix value is a ``[B, 9]`` (matrix33) or ``[B, 16]`` (matrix44) float32 tensor, the
matrix flattened row by row, which is the order of a MaterialX value string (``"m00, m01, m02, m10, ..."``)
and of :data:`mtlx2neural.graph.ir.CHANNELS` (9 and 16).  Kept flat, a matrix is one more ``[B, C]``
value: the element-wise nodes (``add``, ``subtract`` and their float "FA" variants, ``constant``,
``dot``, ``switch``, ``ifgreater``, ``ifgreatereq``, ``ifequal``) need nothing new, and a per-point
matrix broadcasts over the batch like any other value.  :func:`as_square` views it as ``[B, n, n]``.

Convention: MaterialX's row vectors.  Row ``i`` of the matrix is what ``creatematrix`` takes as ``in{i+1}``
and what ``extract`` returns for ``index = i``; a vector is transformed as ``v' = v M`` (so a matrix44's
translation is its last row, applied to a point as ``(x, y, z, 1) M``); ``multiply`` is the product
``in1 in2`` (``in1`` applied first to a row vector), and ``divide`` is ``in1 inverse(in2)``.  That is what
MaterialX's generated GLSL and Slang compute (their ``mx_matrix_mul`` swaps operands to keep that order);
the matrix oracle test checks it with non-symmetric matrices.

``invertmatrix`` and ``divide`` use the adjugate over the determinant, the determinant pushed away from 0
(:func:`mtlx2neural.graph.ops.safe_div`) so that a singular matrix gives large finite values, not Inf/NaN.
"""

from __future__ import annotations

import torch

from mtlx2neural.graph.ops import OPS, op, safe_div

MATRIX_SIZE = {"matrix33": 3, "matrix44": 4}


def as_square(x: torch.Tensor) -> torch.Tensor:
    """A flat matrix value ``[B, n*n]`` (row by row) as ``[B, n, n]`` (``[b, row, column]``)."""
    n = 3 if x.shape[-1] == 9 else 4
    return x.reshape(x.shape[0], n, n)


def flat(m: torch.Tensor) -> torch.Tensor:
    """``[B, n, n]`` -> the flat row-by-row value ``[B, n*n]``."""
    return m.reshape(m.shape[0], -1)


def _minor_det3(m: torch.Tensor) -> torch.Tensor:
    """Determinants ``[B]`` of ``[B, 3, 3]`` by cofactor expansion along the first row."""
    return (m[:, 0, 0] * (m[:, 1, 1] * m[:, 2, 2] - m[:, 1, 2] * m[:, 2, 1])
            - m[:, 0, 1] * (m[:, 1, 0] * m[:, 2, 2] - m[:, 1, 2] * m[:, 2, 0])
            + m[:, 0, 2] * (m[:, 1, 0] * m[:, 2, 1] - m[:, 1, 1] * m[:, 2, 0]))


def _cofactors(m: torch.Tensor) -> torch.Tensor:
    """The cofactor matrix ``[B, n, n]`` of ``m`` ``[B, n, n]`` (n = 3 or 4): C[i, j] = (-1)^(i+j) M_ij."""
    n = m.shape[-1]
    out = torch.empty_like(m)
    for i in range(n):
        rows = [r for r in range(n) if r != i]
        for j in range(n):
            cols = [c for c in range(n) if c != j]
            sub = m[:, rows][:, :, cols]
            if n == 3:
                minor = sub[:, 0, 0] * sub[:, 1, 1] - sub[:, 0, 1] * sub[:, 1, 0]
            else:
                minor = _minor_det3(sub)
            out[:, i, j] = minor if (i + j) % 2 == 0 else -minor
    return out


def determinant(m: torch.Tensor) -> torch.Tensor:
    """Determinants ``[B, 1]`` of square matrices ``[B, n, n]``."""
    if m.shape[-1] == 3:
        return _minor_det3(m)[:, None]
    c = _cofactors(m)
    return (m[:, 0, :] * c[:, 0, :]).sum(-1, keepdim=True)


def inverse(m: torch.Tensor) -> torch.Tensor:
    """Inverses ``[B, n, n]`` of ``m`` ``[B, n, n]``: adjugate / determinant, the determinant kept at
    least 1e-8 in magnitude (a singular matrix gives large finite entries)."""
    c = _cofactors(m)
    det = (m[:, 0, :] * c[:, 0, :]).sum(-1)
    return safe_div(c.transpose(1, 2), det[:, None, None])


def _batched(*xs: torch.Tensor):
    """Square views of flat matrices, expanded to a common batch."""
    b = max(x.shape[0] for x in xs)
    return [as_square(x.expand(b, x.shape[-1])) for x in xs]


def _is_matrix_node(n) -> bool:
    return n.type in MATRIX_SIZE


def _dispatch(category: str, matrix_fn):
    """Register ``matrix_fn`` for ``category``'s nodedefs that output a matrix; the others keep the
    operator :mod:`mtlx2neural.graph.ops` registered (``multiply`` and ``divide`` of matrices are matrix
    products, not element-wise)."""
    base = OPS[category]

    def run(a, n):
        return matrix_fn(a, n) if _is_matrix_node(n) else base(a, n)
    run.__doc__ = f"{category}: the matrix form for matrix outputs, else the element-wise operator."
    op(category)(run)


def _multiply(a, n):
    m1, m2 = _batched(a["in1"], a["in2"])
    return flat(m1 @ m2)


def _divide(a, n):
    m1, m2 = _batched(a["in1"], a["in2"])
    return flat(m1 @ inverse(m2))


_dispatch("multiply", _multiply)
_dispatch("divide", _divide)

_extract_base = OPS["extract"]


@op("extract")
def _extract(a, n):
    """extract: channel ``index`` of a vector/colour, or row ``index`` of a matrix (vector3 of a matrix33,
    vector4 of a matrix44; ``index`` is uniform)."""
    x = a["in"]
    if n.nodedef not in ("ND_extract_matrix33", "ND_extract_matrix44"):
        return _extract_base(a, n)
    size = 3 if x.shape[-1] == 9 else 4
    idx = min(max(int(a["index"].reshape(-1)[0].item()), 0), size - 1)
    return x[:, idx * size:(idx + 1) * size]


@op("transpose")
def _transpose(a, n):
    return flat(as_square(a["in"]).transpose(1, 2))


op("determinant")(lambda a, n: determinant(as_square(a["in"])))
op("invertmatrix")(lambda a, n: flat(inverse(as_square(a["in"]))))


@op("transformmatrix")
def _transformmatrix(a, n):
    """The row vector ``in`` times ``mat``: vector3 by matrix33, vector4 by matrix44; a vector2 by a
    matrix33 (``vector2M3``) and a vector3 by a matrix44 (``vector3M4``) are extended with w = 1 (a point:
    the last row translates) and return their first two or three channels, without a divide by w."""
    v, mat = a["in"], a["mat"]
    (m,) = _batched(mat)
    size = m.shape[-1]
    c = v.shape[-1]
    if c < size:
        v = torch.cat([v, torch.ones(v.shape[0], size - c, dtype=v.dtype, device=v.device)], -1)
    b = max(v.shape[0], m.shape[0])
    out = torch.bmm(v.expand(b, size)[:, None, :], m.expand(b, size, size))[:, 0, :]
    return out[:, :c]


@op("creatematrix")
def _creatematrix(a, n):
    """Rows ``in1``..``in3`` (matrix33 from vector3), ``in1``..``in4`` (matrix44 from vector4), or
    ``in1``..``in4`` as (x, y, z, 0), (x, y, z, 0), (x, y, z, 0), (x, y, z, 1) (matrix44 from vector3:
    ``in4`` is the translation)."""
    size = MATRIX_SIZE[n.type]
    rows = [a[f"in{k + 1}"] for k in range(size)]
    b = max(r.shape[0] for r in rows)
    rows = [r.expand(b, r.shape[-1]) for r in rows]
    if rows[0].shape[-1] < size:  # vector3 rows of a matrix44
        w = [0.0, 0.0, 0.0, 1.0]
        rows = [torch.cat([r, torch.full((b, 1), w[k], dtype=r.dtype, device=r.device)], -1)
                for k, r in enumerate(rows)]
    return torch.cat(rows, -1)
