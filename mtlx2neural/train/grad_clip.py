"""Gradient spikes: clip a step's global gradient norm only where it is far above the run's recent norms.

A step's gradient norm is capped at :data:`SPIKE_FACTOR` times the median norm of the last :data:`WINDOW`
steps, so a rare spike (a batch that hits a sharp lobe the decoder is far from) cannot inflate Adam's second
moments and stall the steps after it, while the run's own scale is left alone. A fixed cap cannot do both: the
gradient norms of a `fast` run range from 0.5 (a rough plastic) to 25-40 (a near-mirror metal), and the earlier
cap of 10 clipped 80 % of the near mirror's steps, the ones whose batches carried its lobe's errors. Without it
the near mirror's sphere views came out at HDR FLIP 0.188 / 0.209 against 0.212 / 0.248 (seeds 0 / 1), and the
samples whose steps it never reached trained the same (docs/history/gradient-clip-2026-12-07.md).
"""

from __future__ import annotations

import math
from collections import deque
from statistics import median

import torch

SPIKE_FACTOR = 10.0
"""A step's gradient norm is capped at this multiple of the recent steps' median (the near mirror's largest
steps reach 3-5x its median)."""
WINDOW = 50
"""Steps whose norms set the median."""
MIN_HISTORY = 10
"""Steps recorded before the cap applies (the first steps of a run set the scale)."""


class SpikeClip:
    """Per-run state of the spike clip: call it after ``backward`` with the parameters Adam steps."""

    def __init__(self, factor: float = SPIKE_FACTOR, window: int = WINDOW, min_history: int = MIN_HISTORY):
        self.factor, self.min_history = float(factor), int(min_history)
        self.norms: deque[float] = deque(maxlen=int(window))

    @property
    def cap(self) -> float:
        """The current cap on the global norm (infinite until :data:`MIN_HISTORY` steps are recorded)."""
        if len(self.norms) < self.min_history:
            return math.inf
        return self.factor * median(self.norms)

    def __call__(self, parameters) -> tuple[float, bool]:
        """Clip the gradients of ``parameters`` (in place) to :attr:`cap`; returns (the norm before clipping,
        whether it was clipped). A non-finite norm is returned unclipped and not recorded (the caller stops the
        run on it). A clipped step records the cap, not its norm, so one spike does not raise the next cap."""
        params = [p for p in parameters if p.grad is not None]
        cap = self.cap
        norm = float(torch.nn.utils.clip_grad_norm_(params, cap)) if params else 0.0
        if not math.isfinite(norm):
            return norm, False
        clipped = norm > cap
        self.norms.append(min(norm, cap))
        return norm, clipped
