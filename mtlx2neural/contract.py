"""The input contract shared by the reference and the neural material (``eval``/``sample``/``pdf``/``albedo``).

Conventions (docs/ARCHITECTURE.md), the same for :class:`~mtlx2neural.reference.ReferenceMaterial` and
:class:`~mtlx2neural.model.neural_material.NeuralMaterial`:

- Directions are ``[N, 3]`` in the local shading frame: z the geometric normal, x the tangent; ``wi``
  points to the viewer, ``wo`` to the light, both away from the surface. ``eval`` returns
  f(wi, wo) * max(0, wo.z) (the cosine included) in linear RGB.
- Directions need not have unit length: every method normalises them the same way. Each vector is
  first divided by its largest absolute component, then by its length, so 1e30- or 1e-30-scaled and
  denormal vectors give the same direction up to rounding, with no overflow or underflow. Vectors of
  unit length to within rounding are used as given.
- A direction is *at or below the horizon* when its normalised z <= 0. A zero vector has no
  direction and counts as below the horizon. There ``eval`` is 0, ``pdf`` is 0, and ``sample``
  returns weight 0 and pdf 0; a *sampled* ``wo`` at or below the horizon also gets weight 0 and pdf 0,
  so ``sample``'s pdf always equals ``pdf(wi, wo)`` of the direction it returns. (``pdf`` therefore
  integrates to 1 minus the probability that ``sample`` fails, not to 1, over the sphere.)
- Any real dtype (float64, float16, bfloat16, integers) on any device is accepted: the numbers are
  normalised in the wider of their dtype and the material's, then converted to the material's dtype
  and device; results come back in the material's dtype (float32 for loaded materials) on its device.
- NaN or +-Inf in any input raises ``ValueError`` naming the argument (nothing is silently replaced);
  so do malformed shapes. Every finite input gives finite outputs.
"""

from __future__ import annotations

import torch

BELOW = (0.0, 0.0, -1.0)  # what a zero vector becomes: a direction straight below the horizon
UNIT_ULPS = 16  # |length^2 - 1| within this many ulps: already unit (a normalised vector is within ~3)


def _tensor(name: str, x) -> torch.Tensor:
    t = x if isinstance(x, torch.Tensor) else torch.as_tensor(x)
    if t.is_complex() or t.dtype == torch.bool:
        raise ValueError(f"{name} must hold real numbers, not {t.dtype}")
    return t


def check_finite(name: str, t: torch.Tensor) -> None:
    """Raise ``ValueError`` naming ``name`` when ``t`` holds NaN or +-Inf."""
    if t.is_floating_point() and not bool(torch.isfinite(t).all()):
        what = "NaN" if bool(torch.isnan(t).any()) else "Inf"
        raise ValueError(f"{name} contains {what}; directions, random numbers and uv must be finite")


def normalize_directions(w: torch.Tensor) -> torch.Tensor:
    """Unit vectors [N,3] from finite float vectors of any length, overflow- and underflow-safe: divided
    by the largest absolute component, then by the length (now in [1, sqrt(3)]). Zero vectors become
    (0, 0, -1), below the horizon.

    Vectors already of unit length to within ``UNIT_ULPS`` ulps of their dtype pass through unchanged,
    so normalising is idempotent: a direction ``sample`` returned gives the very same ``pdf`` when
    passed back, and unit input is used bit for bit as given."""
    n2 = (w * w).sum(-1, keepdim=True)  # inf for huge vectors, which then take the careful path
    unit = (n2 - 1.0).abs() <= UNIT_ULPS * torch.finfo(w.dtype).eps
    m = w.abs().amax(-1, keepdim=True)
    zero = m == 0
    v = w / torch.where(zero, torch.ones_like(m), m)
    v = v / v.norm(dim=-1, keepdim=True).clamp_min(1.0)
    return torch.where(unit, w, torch.where(zero, v.new_tensor(BELOW), v))


def _working_dtype(t: torch.Tensor, dtype: torch.dtype) -> torch.dtype:
    return torch.promote_types(t.dtype, dtype) if t.is_floating_point() else dtype


def prepare_direction(name: str, w, dtype: torch.dtype, device) -> torch.Tensor:
    """One direction argument: checked ([N,3], real, finite), normalised, in ``dtype`` on ``device``."""
    t = _tensor(name, w)
    if t.dim() != 2 or t.shape[-1] != 3:
        raise ValueError(f"{name} must be an [N, 3] tensor of directions, got shape {list(t.shape)}")
    check_finite(name, t)
    t = normalize_directions(t.to(_working_dtype(t, dtype)))
    return t.to(device=device, dtype=dtype)


def prepare_directions(wi, wo, dtype: torch.dtype, device) -> tuple[torch.Tensor, torch.Tensor]:
    """``(wi, wo)`` as unit vectors [N,3] in ``dtype`` on ``device`` (the module's conventions):
    ValueError for NaN/Inf, a shape other than [N,3], or differing N."""
    wi = prepare_direction("wi", wi, dtype, device)
    wo = prepare_direction("wo", wo, dtype, device)
    if wi.shape[0] != wo.shape[0]:
        raise ValueError(f"wi and wo must have the same number of rows; wi has {wi.shape[0]}, wo {wo.shape[0]}")
    return wi, wo


def prepare_values(name: str, x, dtype: torch.dtype, device, rows: int | None = None,
                   width: tuple[int, ...] | None = None) -> torch.Tensor | None:
    """A non-direction input (``u``, ``uv``, ``lod``, ...) checked finite and converted to ``dtype`` on
    ``device``; ``None`` stays ``None``. ``rows``: the number of rows it must have; ``width``: the
    allowed sizes of its last axis (a 2-D tensor then)."""
    if x is None:
        return None
    t = _tensor(name, x)
    if width is not None and (t.dim() != 2 or t.shape[-1] not in width):
        shapes = " or ".join(f"[N, {k}]" for k in width)
        raise ValueError(f"{name} must be an {shapes} tensor, got shape {list(t.shape)}")
    if rows is not None and (t.dim() == 0 or t.shape[0] != rows):
        raise ValueError(f"{name} must have {rows} rows (one per direction), got shape {list(t.shape)}")
    check_finite(name, t)
    return t.to(device=device, dtype=dtype)


def above_horizon(*ws: torch.Tensor) -> torch.Tensor:
    """[N,1] bool: every one of the (normalised) directions ``ws`` has z > 0."""
    ok = ws[0][:, 2:3] > 0
    for w in ws[1:]:
        ok = ok & (w[:, 2:3] > 0)
    return ok


def zero_below_horizon(x: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """``x`` ([N] or [N, C]) where both ``wi`` and ``wo`` are above the horizon, else 0."""
    ok = above_horizon(wi, wo)
    return torch.where(ok[:, 0] if x.dim() == 1 else ok, x, torch.zeros_like(x))
