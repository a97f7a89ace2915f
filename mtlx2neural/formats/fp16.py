"""FP16 quantisation with a range check (docs/ARCHITECTURE.md, "Numerics": check ranges before quantising).

IEEE binary16 represents normal numbers with 6.1035e-5 <= |x| <= 65504.
Before a float32 tensor is rounded to half:

- NaN becomes 0 and +-Inf becomes +-65504 (neither should ever occur; both are reported);
- |x| > 65504 is clamped to +-65504 (reported: it would become Inf);
- 0 < |x| < 6.1035e-5 is **kept**: it is rounded to the nearest FP16 subnormal, which
  has fewer significant bits (an absolute step of 2^-24 = 5.96e-8), and values below
  2^-25 round to 0. Such values are reported with their count, but not flushed, because
  a subnormal still carries the sign and the order of magnitude and shader FP16
  storage (textures, buffers) keeps subnormals. Hardware that flushes FP16 subnormals
  in arithmetic sees 0 instead, an absolute error below 6.1e-5.

Every report is a human-readable line naming the tensor, the count and what was done.
"""

from __future__ import annotations

import numpy as np
import torch

FP16_MAX = 65504.0
"""Largest finite FP16 value."""
FP16_MIN_NORMAL = 2.0 ** -14
"""Smallest positive normal FP16 value (6.1035e-5)."""


def to_fp16(t: torch.Tensor | np.ndarray, what: str) -> tuple[np.ndarray, list[str]]:
    """``t`` as a little-endian float16 NumPy array, and the notes of the range check.

    ``what`` names the tensor in the notes (e.g. "latents level 0, channels 0-3").
    The input is not modified.
    """
    x = t.detach().cpu().double().numpy() if isinstance(t, torch.Tensor) else np.asarray(t, np.float64)
    notes = []
    bad = ~np.isfinite(x)
    if bad.any():
        notes.append(f"{what}: {int(bad.sum())} non-finite value(s) (NaN -> 0, +-Inf -> +-{FP16_MAX:g})")
        x = np.nan_to_num(x, nan=0.0, posinf=FP16_MAX, neginf=-FP16_MAX)
    a = np.abs(x)
    over = a > FP16_MAX
    if over.any():
        notes.append(f"{what}: {int(over.sum())} value(s) beyond the FP16 range (max |x| = {a.max():.6g}) "
                     f"clamped to +-{FP16_MAX:g}")
        x = np.clip(x, -FP16_MAX, FP16_MAX)
    sub = (a > 0) & (a < FP16_MIN_NORMAL)
    if sub.any():
        zero = int(((a > 0) & (a < 2.0 ** -25)).sum())
        notes.append(f"{what}: {int(sub.sum())} value(s) below the FP16 normal range "
                     f"(0 < |x| < {FP16_MIN_NORMAL:.4g}, smallest {a[sub].min():.3g}) kept as FP16 subnormals "
                     f"(not flushed; {zero} of them round to 0)")
    return x.astype("<f2"), notes
