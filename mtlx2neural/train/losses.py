"""Training losses.

The BRDF loss is L1 between log(1 + x / EPS) of prediction and target. The
log compresses the huge dynamic range of near-specular lobes (values of 1e3 and
more next to 1e-3), so one near-delta sample cannot dominate a batch with a
gradient spike, and the offset EPS keeps the log finite and its gradient
bounded (<= 1/EPS) where the target is black. Dividing by EPS makes the loss
linear below EPS and logarithmic above it.
"""

from __future__ import annotations

import torch

EPS = 1e-2  # radiance scale (f * cos) below which errors count linearly


def log_l1(pred: torch.Tensor, target: torch.Tensor, eps: float = EPS) -> torch.Tensor:
    """Mean |log1p(pred/eps) - log1p(target/eps)| over all elements (inputs must be >= 0)."""
    return (torch.log1p(pred.clamp_min(0) / eps) - torch.log1p(target.clamp_min(0) / eps)).abs().mean()
