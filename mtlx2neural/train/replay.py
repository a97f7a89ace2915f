"""Training rows reused over consecutive steps (``TrainConfig.target_reuse``).

A textured material's targets (footprint-filtered, mollified reference BRDF values) cost about three
quarters of a CPU step (BENCHMARKS.md, "Time to quality"). With reuse k, each step draws a k-th of
its BRDF batch fresh and trains on it together with the k - 1 chunks drawn in the steps before, so
every row is trained on in k consecutive steps and the reference is called for a k-th of the rows.
The batch size, the losses and the random numbers of everything else in the step are unchanged;
k = 1 is the plain loop, bit for bit.

Prefetch (``TrainConfig.target_prefetch``) is the other lever on the same cost: the reference's
per-call overhead (many small tensor operations per lobe) dominates at a CPU batch, so drawing the
fresh rows of p steps in one call and serving them a p-th at a time costs less per row (Leaf on
2 cores: 39 ms per 2048 rows one step at a time, 16 ms drawn 16 steps at once). Step j of a
prefetched draw takes its rows j, j + p, j + 2p, ..., so every step keeps its share of each kind of
row that ``draw`` puts in blocks (grazing rows, rows near the lobes). The rows are drawn with the
settings of the step that draws them (its mollification angle), at most p - 1 steps early.
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

    def __init__(self, batch: int, reuse: int, prefetch: int = 1):
        if reuse < 1 or reuse > batch:
            raise ValueError(f"target reuse {reuse} must be between 1 and the batch ({batch})")
        if prefetch < 1:
            raise ValueError(f"target prefetch {prefetch} must be at least 1")
        self.batch_size, self.reuse, self.prefetch = batch, reuse, prefetch
        self.sizes = [batch // reuse + (i < batch % reuse) for i in range(reuse)]
        self.ring: list[Rows] = []
        self.oldest = 0  # the chunk the next call redraws
        self.ahead: dict[int, tuple[Rows, int]] = {}  # size -> (rows drawn for `prefetch` requests, served)

    def batch(self, draw: Callable[[int], Rows]) -> Rows:
        if self.reuse == 1:
            return self._fresh(draw, self.batch_size)
        if not self.ring:
            self.ring = [self._fresh(draw, n) for n in self.sizes]
        else:
            self.ring[self.oldest] = self._fresh(draw, self.sizes[self.oldest])
            self.oldest = (self.oldest + 1) % self.reuse
        return tuple(torch.cat(parts) for parts in zip(*self.ring))

    def set_prefetch(self, prefetch: int) -> None:
        """Draw the rows of ``prefetch`` requests per call from the next request on (rows drawn ahead for the
        old setting are dropped)."""
        if prefetch < 1:
            raise ValueError(f"target prefetch {prefetch} must be at least 1")
        self.prefetch, self.ahead = prefetch, {}

    def _fresh(self, draw: Callable[[int], Rows], n: int) -> Rows:
        """``draw(n)``'s worth of fresh rows: with prefetch p, the next p-th (strided) of one ``draw(p * n)``."""
        if self.prefetch == 1:
            return draw(n)
        rows, served = self.ahead.get(n, ((), self.prefetch))
        if served == self.prefetch:
            rows, served = draw(n * self.prefetch), 0
        self.ahead[n] = (rows, served + 1)
        return tuple(t[served::self.prefetch].contiguous() for t in rows)

    # -- checkpoints: a resumed run continues with the same rows ---------------------------
    def state_dict(self) -> dict:
        return {"ring": [tuple(t.cpu() for t in rows) for rows in self.ring], "oldest": self.oldest,
                "ahead": {n: (tuple(t.cpu() for t in rows), served) for n, (rows, served) in self.ahead.items()}}

    def load_state_dict(self, state: dict | None, device) -> None:
        state = state or {}
        ring = state.get("ring", [])
        if len(ring) != self.reuse:  # none saved (K = 1, an older checkpoint) or another K: start afresh
            ring = []
        self.ring = [tuple(t.to(device) for t in rows) for rows in ring]
        self.oldest = state.get("oldest", 0) if self.ring else 0
        ahead = state.get("ahead", {}) if self.prefetch > 1 else {}
        self.ahead = {n: (tuple(t.to(device) for t in rows), served) for n, (rows, served) in ahead.items()
                      if served <= self.prefetch and rows and rows[0].shape[0] >= self.prefetch}
