"""Training rows drawn in a second process (``train.row_process``): the requests predict every batch
of a joint training, the child answers them with the rows an in-process replay draws, and its failures
reach the parent as errors (tiny CPU runs of two uniform materials)."""

from __future__ import annotations

import functools
import math

import pytest
import torch
from materials import broken_row_factory, layered_spheres_trainers

from mtlx2neural.train.row_process import Request, RowProcess, serve_rows
from mtlx2neural.train.shared import FLOOR_PREFETCH, SharedTrainer, latent_steps
from mtlx2neural.train.trainer import at_mollify_floor

NAMES = ("CarPaint", "Plastic")
SETTINGS = dict(iterations=40, batch=256, seed=5)


def _factory(tmp_path):
    return functools.partial(layered_spheres_trainers, NAMES, str(tmp_path), **SETTINGS)


def test_the_requests_are_the_calls_a_joint_training_makes(tmp_path, monkeypatch):
    trainers = _factory(tmp_path)()
    shared = SharedTrainer(trainers)
    requests = shared.requests()
    calls = []
    for k, t in enumerate(trainers):
        real = t.step_rows  # every batch a joint step or a latent fine-tune trains on
        monkeypatch.setattr(t, "step_rows", lambda k=k, t=t, real=real: calls.append((k, t.step, t.replay.prefetch))
                            or real())
    shared.run(progress=False)
    # the same materials, steps and prefetch, in the same order, joint steps and latent fine-tunes alike
    assert [(r.material, r.step, r.prefetch) for r in requests] == calls
    cfg = trainers[0].cfg
    floor = next(s for s in range(cfg.iterations) if at_mollify_floor(cfg, s))
    assert 0 < floor < cfg.iterations
    assert {r.prefetch for r in requests if r.step < floor} == {cfg.target_prefetch}
    assert {r.prefetch for r in requests if r.step >= floor} == {FLOOR_PREFETCH}
    latent = [r for r in requests if r.step == cfg.iterations]
    assert len(latent) == 2 * latent_steps(cfg.iterations)
    assert [r.fresh for r in requests].count(True) == 4  # each material's first joint step and first latent step


def test_serve_rows_draws_as_the_replay_would(tmp_path, monkeypatch):
    """serve_rows calls each trainer's draw_rows with the same (step, rows) as the in-process replay of a
    joint training: one step's rows at a time while the mollification decays, FLOOR_PREFETCH steps' from
    its floor."""
    trainers = _factory(tmp_path)()
    requests = SharedTrainer(trainers).requests()
    draws = {k: [] for k in range(len(trainers))}
    for k, t in enumerate(trainers):
        real = t.draw_rows
        monkeypatch.setattr(t, "draw_rows", lambda n, k=k, t=t, real=real: draws[k].append((t.step, n)) or real(n))
    served = list(serve_rows(trainers, requests))
    assert len(served) == len(requests)
    assert all(rows[0].shape[0] == rows[-1].shape[0] >= SETTINGS["batch"] for rows in served)
    floor = next(r.step for r in requests if r.material == 0 and r.prefetch == FLOOR_PREFETCH)
    batch = SETTINGS["batch"]
    expected = [(s, batch) for s in range(floor)]
    expected += [(s, batch * FLOOR_PREFETCH) for s in range(floor, SETTINGS["iterations"], FLOOR_PREFETCH)]
    # the latent fine-tune: a fresh replay at the schedule's end
    expected += [(SETTINGS["iterations"], batch * FLOOR_PREFETCH)] * math.ceil(
        latent_steps(SETTINGS["iterations"]) / FLOOR_PREFETCH)
    assert draws[0] == expected and draws[1] == expected


def test_the_process_serves_the_rows_drawn_here(tmp_path):
    """Bit for bit: the child (one torch thread) and this process at one thread run the same draws from the
    same seeds."""
    factory = _factory(tmp_path)
    here = factory()
    requests = SharedTrainer(here).requests()[:60]
    rows = RowProcess(factory)
    try:
        rows.plan([0, 1], [t.cfg for t in here], requests)
        got = [rows.next(r.material) for r in requests]
    finally:
        rows.close()
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        want = list(serve_rows(here, requests))
    finally:
        torch.set_num_threads(threads)
    for a, b in zip(got, want, strict=True):
        assert len(a) == len(b) and all(torch.equal(x, y) for x, y in zip(a, b))


def test_a_request_out_of_order_is_refused(tmp_path):
    rows = RowProcess(_factory(tmp_path))
    try:
        rows.plan([0, 1], [t.cfg for t in _factory(tmp_path)()], [Request(0, 0, 1, True)])
        with pytest.raises(RuntimeError, match="asked for material 1, planned for 0"):
            rows.next(1)
        with pytest.raises(RuntimeError, match="more training rows asked for than were planned"):
            rows.next(0)
    finally:
        rows.close()


@pytest.mark.parametrize("how, message", [("raise", "ValueError: this factory cannot prepare its materials"),
                                          ("exit", r"ended without an answer \(exit code 3\)")])
def test_a_failing_process_is_an_error_here(how, message):
    rows = RowProcess(functools.partial(broken_row_factory, how))
    try:
        rows.plan([0], [None], [Request(0, 0, 1, True)])
        with pytest.raises(RuntimeError, match=message):
            rows.next(0)
    finally:
        rows.close()
