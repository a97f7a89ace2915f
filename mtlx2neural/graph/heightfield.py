"""Torch operator for MaterialX's ``heighttonormal`` (and through its library nodegraph, ``bump``).

MaterialX's shader builds a tangent frame from the screen-space derivatives (``dFdx``/``dFdy``) of the
height and of the node's ``texcoord`` input and returns its normal, encoded as ``n * 0.5 + 0.5``.  With
h' = height * scale / 16 (the 1/16 keeps parity with a Sobel filter) and (s, t) the texcoord, that normal
is normalize(-dh'/ds, -dh'/dt, 1) whatever the screen parametrisation is, as long as it is not degenerate:
the cross product of (ds/dx, dt/dx, dh'/dx) and (ds/dy, dt/dy, dh'/dy) is det(J) * (-dh'/ds, -dh'/dt, 1),
J the Jacobian of (s, t) over the screen.  So here the "screen" is the evaluator's uv: the operator builds
the same frame from the exact derivatives of height and texcoord with respect to uv (autograd, per point:
a shading point's height depends only on its own uv), flips it when it points down (mirrored texture
coordinates), and returns (0, 0, 1) where it is degenerate (a texcoord that does not vary with uv, or
varies along one direction only: |n|^2 < 1e-16, MaterialX's test).  The result is a tangent-space normal
in the texcoord's frame: x along +s, y along +t (MaterialX's v-up convention), z out of the surface.

Derivatives: :meth:`~mtlx2neural.graph.evaluator.GraphEvaluator.run` asks :func:`wants_uv_grad` whether the
nodes it runs contain ``heighttonormal``; only then it runs them again through :func:`run_differentiable`,
which makes uv require grad (under ``torch.enable_grad``, so callers inside ``torch.no_grad`` work) and
returns the values detached.  Graphs without the node pay nothing.  A shader's derivatives are finite
differences over a pixel quad; these are their limit (exact), which a texture's bilinear interpolation
makes piecewise constant per texel, as a finite difference within one texel would see.  A folded
(uv-independent) height has zero derivatives: the flat normal (0.5, 0.5, 1).
"""

from __future__ import annotations

import contextvars

import torch

from mtlx2neural.graph.ops import normalize, op

DERIVATIVE_NODES = frozenset({"heighttonormal"})
SOBEL_SCALE = 1.0 / 16.0  # MaterialX's parity factor with a Sobel filter
_DEGENERATE = 1e-8 * 1e-8  # |n|^2 below this: the flat normal (MaterialX's M_FLOAT_EPS squared)
# (uv that requires grad, whether the derivatives themselves must stay differentiable) during run_differentiable
_UV: contextvars.ContextVar[tuple[torch.Tensor, bool] | None] = contextvars.ContextVar("heightfield_uv", default=None)


def wants_uv_grad(graph, nodes: list[int]) -> bool:
    """Whether evaluating ``nodes`` of ``graph`` needs derivatives with respect to uv (and no
    :func:`run_differentiable` is already providing them)."""
    return _UV.get() is None and any(graph[i].category in DERIVATIVE_NODES for i in nodes)


def run_differentiable(run, nodes: list[int], uv: torch.Tensor, *args):
    """``run(nodes, uv', *args)`` with uv' a copy of ``uv`` [N, 2] that requires grad, read by the
    ``heighttonormal`` operators; the returned tensors are detached from uv'.  When the caller's ``uv``
    already requires grad under grad mode, it is used itself and nothing is detached (the derivatives are
    then built with ``create_graph``, so the normals stay differentiable)."""
    keep = uv.requires_grad and torch.is_grad_enabled()
    with torch.enable_grad():
        uv_g = uv if keep else uv.detach().clone().requires_grad_(True)
        token = _UV.set((uv_g, keep))
        try:
            env = run(nodes, uv_g, *args)
        finally:
            _UV.reset(token)
    if keep:
        return env
    return {k: v.detach() if isinstance(v, torch.Tensor) else v for k, v in env.items()}


def _grad(y: torch.Tensor, uv: torch.Tensor, create_graph: bool) -> torch.Tensor:
    """Per-row derivative [N, 2] of the per-row scalar ``y`` [N, 1] (or [1, 1]) with respect to ``uv``
    (a row's value depends only on its own uv, so the gradient of the sum is the per-row derivative)."""
    if not y.requires_grad:
        return torch.zeros_like(uv)
    (g,) = torch.autograd.grad(y.sum(), uv, retain_graph=True, create_graph=create_graph, allow_unused=True)
    return torch.zeros_like(uv) if g is None else g


@op("heighttonormal")
def _heighttonormal(a, n):
    """Tangent-space normal of the height field ``in`` * ``scale`` / 16 over ``texcoord``, encoded in
    [0, 1]^3 as n * 0.5 + 0.5 ([B, 3]); see the module docstring for the frame and the degenerate case."""
    height, scale, tc = a["in"], a["scale"], a["texcoord"]
    active = _UV.get()
    uv, create = active if active is not None else (None, False)
    rows = max(height.shape[0], tc.shape[0], scale.shape[0])
    if uv is None or uv.shape[0] != rows or not (height.requires_grad or scale.requires_grad):
        flat = torch.tensor([[0.5, 0.5, 1.0]], dtype=height.dtype, device=height.device)
        return flat.expand(rows, 3)
    dh = _grad(height * scale * SOBEL_SCALE, uv, create)  # [N, 2]: (dh'/du, dh'/dv)
    if tc is uv:  # the texcoord is the uv itself: its Jacobian is the identity
        ds, dt = torch.zeros_like(uv), torch.zeros_like(uv)
        ds[:, 0] = 1.0
        dt[:, 1] = 1.0
    else:
        ds, dt = _grad(tc[:, 0:1], uv, create), _grad(tc[:, 1:2], uv, create)
    tangent = torch.stack([ds[:, 0], dt[:, 0], dh[:, 0]], -1)  # along u
    bitangent = torch.stack([ds[:, 1], dt[:, 1], dh[:, 1]], -1)  # along v
    nrm = torch.linalg.cross(tangent, bitangent, dim=-1)
    flat = torch.tensor([0.0, 0.0, 1.0], dtype=nrm.dtype, device=nrm.device).expand_as(nrm)
    nrm = torch.where(nrm[:, 2:3] < 0, -nrm, nrm)
    nrm = torch.where((nrm * nrm).sum(-1, keepdim=True) < _DEGENERATE, flat, nrm)
    return normalize(nrm) * 0.5 + 0.5
