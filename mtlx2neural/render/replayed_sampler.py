"""A sampler whose draws are computed once and replayed for every material rendered with them.

:func:`.renderer.compare_many` renders the reference and each model of a view with the same seed and the
same sampler (common random numbers), so the sampler is asked the same questions, in the same order, by
every render: the same ``sample(wi, u, at)`` and ``pdf(wi, wo, at)`` calls. :class:`ReplayedSampler`
answers them from a recording of the first render. Under the summary's sky view, whose sampler mixes the
reference's and the model's (:class:`.mixture_sampler.MixtureSampler`), those calls are about two fifths
of a render's time.

A call is replayed only when its inputs equal the recorded call's exactly (``torch.equal`` on every
tensor); from the first call that differs (a cut-out whose coverage differs from the reference's sends
other rays to the next layer) the wrapper computes every call, so the result is always what the sampler
itself would return.
"""

from __future__ import annotations

import torch

from mtlx2neural.contract import as_point


def _fields(wi: torch.Tensor, x: torch.Tensor, at) -> tuple:
    """A call's inputs, flattened: ``wi``, ``u`` or ``wo``, and the shading point's fields and parameters."""
    p = as_point(at)
    params = tuple(sorted((p.params or {}).items()))
    return (wi, x, p.uv, p.lod, p.u_level, *(f for item in params for f in item))


def _same(a: tuple, b: tuple) -> bool:
    if len(a) != len(b):
        return False
    for x, y in zip(a, b):
        if isinstance(x, torch.Tensor) != isinstance(y, torch.Tensor):
            return False
        if isinstance(x, torch.Tensor):
            if x.shape != y.shape or x.dtype != y.dtype or not torch.equal(x, y):
                return False
        elif x is not y and x != y:
            return False
    return True


class ReplayedSampler:
    """``sample`` and ``pdf`` of ``sampler`` (the :class:`~mtlx2neural.contract.Material` contract's),
    recorded during the first render and replayed in the later ones, in the recorded order (module
    docstring). Call :meth:`start` before each render; before the first, calls pass straight through."""

    def __init__(self, sampler):
        self.sampler = sampler
        self.calls: list[tuple[str, tuple, object]] = []
        self.renders = 0
        self.recording = self.replaying = False  # a plain pass-through until start()
        self.position = 0
        self.replayed = 0
        """Calls answered from the recording (for tests and profiles)."""

    def start(self) -> None:
        """Begin a render: the first one records, every later one replays from the first call."""
        self.recording, self.replaying = self.renders == 0, self.renders > 0
        self.position, self.renders = 0, self.renders + 1

    def _answer(self, kind: str, fields: tuple, compute):
        if self.recording:  # the inputs are kept as copies, in case a caller reuses its tensors
            out = compute()
            self.calls.append((kind, tuple(f.clone() if isinstance(f, torch.Tensor) else f for f in fields), out))
            return out
        if self.replaying and self.position < len(self.calls):
            k, recorded, out = self.calls[self.position]
            if k == kind and _same(recorded, fields):
                self.position += 1
                self.replayed += 1
                return out
        self.replaying = False  # diverged (or passing through): compute the rest of this render
        return compute()

    def sample(self, wi: torch.Tensor, u: torch.Tensor, at=None):
        return self._answer("sample", _fields(wi, u, at), lambda: self.sampler.sample(wi, u, at))

    def pdf(self, wi: torch.Tensor, wo: torch.Tensor, at=None) -> torch.Tensor:
        return self._answer("pdf", _fields(wi, wo, at), lambda: self.sampler.pdf(wi, wo, at))
