"""Training rows reused over consecutive steps (``TrainConfig.target_reuse``).

A textured material's targets (footprint-filtered, mollified reference BRDF values) cost about three
quarters of a CPU step (BENCHMARKS.md, "Time to quality"). With reuse k, each step draws a k-th of
its BRDF batch fresh and trains on it together with the k - 1 chunks drawn in the steps before, so
every row is trained on in k consecutive steps and the reference is called for a k-th of the rows.
The batch size, the losses and the random numbers of everything else in the step are unchanged;
k = 1 is the plain loop, bit for bit.
"""

from __future__ import annotations

from typing import Callable

import torch

Rows = tuple[torch.Tensor, ...]


class RowReplay:
    """A ring of ``reuse`` chunks of training rows whose sizes add up to ``batch``.

    :meth:`batch` refreshes the oldest chunk (all of them on the first call) with ``draw(size)`` and
    returns every chunk's rows concatenated, field by field. ``draw(n)`` returns a tuple of tensors
    whose first dimension is the row count (it may add rows of its own, e.g. grazing rows in
    proportion to ``n``)."""

    def __init__(self, batch: int, reuse: int):
        if reuse < 1 or reuse > batch:
            raise ValueError(f"target reuse {reuse} must be between 1 and the batch ({batch})")
        self.batch_size, self.reuse = batch, reuse
        self.sizes = [batch // reuse + (i < batch % reuse) for i in range(reuse)]
        self.ring: list[Rows] = []
        self.oldest = 0  # the chunk the next call redraws

    def batch(self, draw: Callable[[int], Rows]) -> Rows:
        if self.reuse == 1:
            return draw(self.batch_size)
        if not self.ring:
            self.ring = [draw(n) for n in self.sizes]
        else:
            self.ring[self.oldest] = draw(self.sizes[self.oldest])
            self.oldest = (self.oldest + 1) % self.reuse
        return tuple(torch.cat(parts) for parts in zip(*self.ring))

    # -- checkpoints: a resumed run continues with the same rows ---------------------------
    def state_dict(self) -> dict:
        return {"ring": [tuple(t.cpu() for t in rows) for rows in self.ring], "oldest": self.oldest}

    def load_state_dict(self, state: dict | None, device) -> None:
        state = state or {}
        ring = state.get("ring", [])
        if len(ring) != self.reuse:  # none saved (K = 1, an older checkpoint) or another K: start afresh
            ring = []
        self.ring = [tuple(t.to(device) for t in rows) for rows in ring]
        self.oldest = state.get("oldest", 0) if self.ring else 0
