"""Training rows drawn in a second process while this one trains the networks (``--network scene`` on a CPU).

A joint step (:mod:`.shared`) spends about half its time in the reference: drawing each material's rows
and their footprint-filtered, mollified targets (:meth:`~.trainer.Trainer.draw_rows`). Those rows depend
on the schedule (the step sets the mollification angle) but never on the networks, so another process
can draw them ahead while this one runs the networks' forward and backward passes. On two cores the
networks then use one and the reference the other; torch's second thread gave the joint steps only
about 9 % (the scene sample, 2026-12-06: 16.0 s with two threads, 17.4 s with one).

The protocol is a fixed list of :class:`Request` s, one per batch the parent trains on
(``Trainer.step_rows``), in the order it takes them: which material, at which step of its schedule,
with which prefetch (:class:`~.replay.RowReplay`), and whether that batch starts a fresh replay (the
latent fine-tune does).
:func:`serve_rows` answers them with one trainer per material, each drawing from its own generator, as
an in-process :class:`~.replay.RowReplay` would; the child runs it and sends each answer through a
bounded queue (numpy arrays), and :class:`RowProcess` hands them out in order, checking the material.

The child builds its trainers with ``factory()``, a picklable callable (the pipeline's preparation of
each material, without writing into its folder), started before the parent prepares its own, so its
imports overlap the parent's work. A failure in the child reaches the parent as a ``RuntimeError``
naming it; a child that ends without an answer (a native library's ``exit()``, a kill) as one too,
within a second.
"""

from __future__ import annotations

import collections
import os
import queue
import signal
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import torch

from mtlx2neural.train.replay import RowReplay, Rows

QUEUE_ROWS = 64
"""Answers the child may draw ahead of the parent (each a step's rows of one material: tens of kB)."""
POLL_SECONDS = 1.0
"""How often a waiting parent checks that the child is alive."""


@contextmanager
def spawn_threads(threads: int):
    """``OMP_NUM_THREADS``/``MKL_NUM_THREADS`` = ``threads`` while processes spawned in it start (their OpenMP
    runtime reads them once)."""
    keys = ("OMP_NUM_THREADS", "MKL_NUM_THREADS")
    old = {k: os.environ.get(k) for k in keys}
    os.environ.update({k: str(threads) for k in keys})
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@dataclass(frozen=True)
class Request:
    """One batch's rows (a ``Trainer.step_rows`` call): ``material`` (index into the trainers), the
    trainer's ``step`` when it draws them (its mollification angle), the replay's ``prefetch`` from then
    on, and ``fresh``: a new replay starts with this batch (rows drawn ahead for the old one are dropped)."""

    material: int
    step: int
    prefetch: int
    fresh: bool = False


def serve_rows(trainers: list, requests: list[Request]) -> Iterator[Rows]:
    """The rows of each request in turn, drawn by ``trainers[request.material]`` (its
    :meth:`~.trainer.Trainer.draw_rows` through a :class:`~.replay.RowReplay` of its ``cfg``'s batch and
    reuse, built when a request is ``fresh`` and re-prefetched when a request's prefetch differs)."""
    replays: dict[int, RowReplay] = {}
    for r in requests:
        t = trainers[r.material]
        cfg = t.cfg
        replay = replays.get(r.material)
        if replay is None or r.fresh:
            replay = replays[r.material] = RowReplay(cfg.batch, cfg.target_reuse, r.prefetch)
        elif replay.prefetch != r.prefetch:
            replay.set_prefetch(r.prefetch)
        t.step = r.step
        yield replay.batch(t.draw_rows)


def _serve(factory: Callable[[], list], conn, out) -> None:
    """The child: build the trainers, wait for the plan, answer every request (module docstring)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops it; Ctrl-C is the parent's to handle
    torch.set_num_threads(1)
    try:
        trainers = factory()
        plan = conn.recv()
        if plan is None:
            return
        indices, cfgs, requests = plan
        chosen = []
        for i, cfg in zip(indices, cfgs):
            if trainers[i] is None:
                raise RuntimeError(f"material {i} could not be prepared in the row process")
            trainers[i].cfg = cfg
            chosen.append(trainers[i])
        for rows in serve_rows(chosen, requests):
            out.put(tuple(x.detach().cpu().numpy() for x in rows))
    except BaseException as exc:  # noqa: BLE001 - every failure goes to the parent as text
        out.put(f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=6)}")


class RowProcess:
    """A child process drawing training rows (module docstring). Start it early with ``factory``; then
    :meth:`plan` the requests, :meth:`next` each one's rows in order, and :meth:`close` it."""

    def __init__(self, factory: Callable[[], list]):
        import multiprocessing

        ctx = multiprocessing.get_context("spawn")
        self._conn, child_conn = ctx.Pipe()
        self._queue = ctx.Queue(maxsize=QUEUE_ROWS)
        self._left: collections.deque[Request] = collections.deque()
        self._planned = False
        with spawn_threads(1):  # one thread from the start: the other core is the parent's
            self._proc = ctx.Process(target=_serve, args=(factory, child_conn, self._queue), daemon=True,
                                     name="mtlx2neural-rows")
            self._proc.start()
        child_conn.close()

    def plan(self, indices: list[int], cfgs: list, requests: list[Request]) -> None:
        """Send the plan: the factory's trainers ``indices`` (in the parent's order, each with its ``cfgs``
        entry, the schedule it trains with) answer ``requests`` (their ``material``: a position in
        ``indices``)."""
        self._conn.send((list(indices), list(cfgs), list(requests)))
        self._left.extend(requests)
        self._planned = True

    def next(self, material: int) -> Rows:
        """The next request's rows (CPU tensors); ``material`` must be that request's."""
        if not self._left:
            raise RuntimeError("more training rows asked for than were planned")
        expected = self._left.popleft()
        if expected.material != material:
            raise RuntimeError(f"training rows asked for material {material}, planned for {expected.material}")
        while True:
            try:
                item = self._queue.get(timeout=POLL_SECONDS)
                break
            except queue.Empty:
                if not self._proc.is_alive():
                    raise RuntimeError(f"the process drawing training rows ended without an answer (exit code "
                                       f"{self._proc.exitcode})") from None
        if isinstance(item, str):
            raise RuntimeError(f"drawing training rows failed in its process: {item}")
        return tuple(torch.from_numpy(x) for x in item)

    def close(self) -> None:
        """Stop the child (at once: whatever it drew ahead is dropped)."""
        try:
            if not self._planned:
                self._conn.send(None)
        except (OSError, ValueError):
            pass
        if self._proc.is_alive():
            self._proc.terminate()
        self._proc.join(timeout=5)
        self._queue.cancel_join_thread()
        self._queue.close()
        self._conn.close()


class RemoteReplay:
    """A trainer's ``replay`` whose rows come from a :class:`RowProcess` (``material``: the trainer's index
    in its plan), moved to ``device``. Checkpoints hold no rows for it (a ``--network scene`` run does not
    resume)."""

    def __init__(self, rows: RowProcess, material: int, device):
        self.rows, self.material, self.device = rows, material, device

    def batch(self, draw=None) -> Rows:
        return tuple(t.to(self.device) for t in self.rows.next(self.material))

    def state_dict(self) -> dict:
        return {}
