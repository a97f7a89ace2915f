"""Training rows reused over consecutive steps and drawn ahead (train/replay.py, TrainConfig.target_reuse and
target_prefetch)."""

from __future__ import annotations

import pytest
import torch
from materials import layered_spheres_material

from mtlx2neural.errors import InputError
from mtlx2neural.train.config import preset, validate_config
from mtlx2neural.train.replay import RowReplay
from mtlx2neural.train.trainer import Trainer, TrainingInterrupted


@pytest.fixture(scope="module")
def carpaint():
    return layered_spheres_material("CarPaint")


class Counter:
    """draw(n): rows numbered in the order they were drawn, plus one extra row per 4 (like grazing rows)."""

    def __init__(self):
        self.next, self.sizes = 0, []

    def __call__(self, n):
        self.sizes.append(n)
        m = n + n // 4
        ids = torch.arange(self.next, self.next + m)
        self.next += m
        return ids, ids.float() * 2


def test_every_row_is_trained_on_in_k_consecutive_steps():
    replay, draw = RowReplay(10, 3), Counter()
    seen: dict[int, list[int]] = {}
    for step in range(12):
        ids, doubled = replay.batch(draw)
        assert torch.equal(doubled, ids.float() * 2)  # fields stay row-aligned
        assert len(ids) == len(set(ids.tolist()))
        for i in ids.tolist():
            seen.setdefault(i, []).append(step)
    # First call: the whole batch in three chunks (4 + 3 + 3 rows); then one chunk per step, oldest first.
    assert draw.sizes == ([4, 3, 3] * 5)[:3 + 11]
    checked = 0
    for i, steps in seen.items():
        if 1 <= steps[0] <= 11 - 2:  # drawn after the first call, and with three steps left to live
            assert steps == [steps[0], steps[0] + 1, steps[0] + 2], (i, steps)
            checked += 1
    assert checked == 3 * (5 + 3 + 3)  # steps 1-9 redraw chunks of 4, 3, 3 rows (+1 extra per 4)


def test_reuse_one_draws_the_whole_batch_every_step():
    replay, draw = RowReplay(8, 1), Counter()
    a, _ = replay.batch(draw)
    b, _ = replay.batch(draw)
    assert draw.sizes == [8, 8] and not set(a.tolist()) & set(b.tolist())
    with pytest.raises(ValueError, match="between 1 and the batch"):
        RowReplay(8, 9)


def test_reuse_is_validated_against_the_batch():
    validate_config(preset("fast", batch=64, target_reuse=64))
    for bad in (0, 65):
        with pytest.raises(InputError, match="target_reuse"):
            validate_config(preset("fast", batch=64, target_reuse=bad))


def test_the_reference_sees_a_kth_of_the_rows(carpaint, tmp_path):
    ref, stack = carpaint
    tr = Trainer(ref, stack, preset("fast", iterations=8, batch=256, target_reuse=4, seed=3), tmp_path)
    rows = []
    real = tr._targets
    tr._targets = lambda wi, *rest: rows.append(wi.shape[0]) or real(wi, *rest)
    tr.run(progress=False)
    assert rows == [64] * 4 + [64] * 7  # the first step fills the ring, then one chunk per step


def test_resume_continues_with_the_same_rows(carpaint, tmp_path, monkeypatch):
    """Interrupted and resumed equals uninterrupted, bit for bit: the ring is in the checkpoint."""
    ref, stack = carpaint
    cfg = preset("fast", iterations=12, batch=128, target_reuse=3, checkpoint_every=1000, seed=4)
    straight = Trainer(ref, stack, cfg, tmp_path / "a").run(progress=False).state_dict()
    _assert_resumed_equals(straight, ref, stack, cfg, tmp_path / "b", monkeypatch)


def _assert_resumed_equals(straight: dict, ref, stack, cfg, folder, monkeypatch, at: int = 5) -> None:
    """A run of ``cfg`` interrupted at step ``at`` and resumed ends with the weights ``straight``, bit for bit."""
    tr = Trainer(ref, stack, cfg, folder)
    real_step = tr.train_step
    monkeypatch.setattr(tr, "train_step", lambda: (_ for _ in ()).throw(KeyboardInterrupt) if tr.step == at
                        else real_step())
    with pytest.raises(TrainingInterrupted):
        tr.run(progress=False)
    again = Trainer(ref, stack, cfg, folder)
    assert again.resume() and again.step == at
    resumed = again.run(progress=False).state_dict()
    assert all(torch.equal(straight[k], resumed[k]) for k in straight)


def test_prefetch_draws_p_steps_at_once_and_serves_each_row_once():
    """Prefetch 4: one draw per 4 steps, of 4x the rows; each step takes a strided quarter, so the extra
    rows ``draw`` puts at the end (one per 4, like grazing rows) spread over the steps; no row twice."""
    replay, draw = RowReplay(8, 1, prefetch=4), Counter()
    batches = [replay.batch(draw) for _ in range(8)]
    assert draw.sizes == [32, 32]
    ids = torch.cat([b[0] for b in batches])
    assert len(ids) == 2 * 40 and len(set(ids.tolist())) == 80
    for ids, doubled in batches:
        assert len(ids) == 10 and torch.equal(doubled, ids.float() * 2)
        assert int((ids % 40 >= 32).sum()) == 2  # each step gets two of the draw's eight extra rows
    with pytest.raises(ValueError, match="prefetch"):
        RowReplay(8, 1, prefetch=0)
    # a new setting applies from the next request: rows drawn ahead for the old one are dropped
    replay, draw = RowReplay(8, 1, prefetch=1), Counter()
    replay.batch(draw)
    replay.set_prefetch(4)
    assert [len(replay.batch(draw)[0]) for _ in range(5)] == [10] * 5 and draw.sizes == [8, 32, 32]
    with pytest.raises(ValueError, match="prefetch"):
        replay.set_prefetch(0)
    with pytest.raises(InputError, match="target_prefetch"):
        validate_config(preset("fast", target_prefetch=0))


def test_prefetch_with_reuse_and_resume_is_bit_for_bit(carpaint, tmp_path, monkeypatch):
    """Prefetch combines with reuse (each chunk size drawn ahead on its own), the reference sees a P-th of
    the calls, and a run interrupted between two draws resumes with the rows drawn ahead (checkpoint)."""
    ref, stack = carpaint
    cfg = preset("fast", iterations=10, batch=128, target_reuse=2, target_prefetch=4, checkpoint_every=1000, seed=5)
    tr = Trainer(ref, stack, cfg, tmp_path / "a")
    calls = []
    real = tr._targets
    tr._targets = lambda wi, *rest: calls.append(wi.shape[0]) or real(wi, *rest)
    straight = tr.run(progress=False).state_dict()
    assert len(calls) == 3  # steps 0-9 request 11 chunks of 64 rows: drawn 4 at a time
    _assert_resumed_equals(straight, ref, stack, cfg, tmp_path / "b", monkeypatch)
