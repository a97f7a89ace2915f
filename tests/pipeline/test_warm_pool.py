"""A pool started ahead of its jobs (``pipeline.workers.WarmPool``): its processes exist before any job, run at
a lower priority with the pool's torch threads, and ``run_jobs`` closes it whatever it ran."""

from __future__ import annotations

import os
import time

import pytest
import torch

from mtlx2neural.pipeline.workers import WARM_NICE, WarmPool, available_cpus, run_jobs


def _niceness_and_threads() -> tuple[int, int, int]:
    return os.getpid(), os.nice(0), torch.get_num_threads()


@pytest.mark.skipif(not hasattr(os, "nice"), reason="POSIX nice is not available here")
def test_its_processes_start_before_any_job_at_a_lower_priority():
    pool = WarmPool(2)
    try:
        deadline = time.time() + 60
        while len(pool.executor._processes or {}) < 2 and time.time() < deadline:
            time.sleep(0.05)
        started = set(pool.executor._processes)
        assert len(started) == 2  # both spawned at construction, not at the first job
        answers = {pool.executor.submit(_niceness_and_threads).result(timeout=60) for _ in range(8)}
        assert {pid for pid, _, _ in answers} <= started
        assert {nice for _, nice, _ in answers} == {min(19, os.nice(0) + WARM_NICE)}
        assert {threads for _, _, threads in answers} == {max(1, available_cpus() // 2)}
    finally:
        pool.close()


def test_run_jobs_closes_the_pool_it_was_given():
    pool = WarmPool(2)
    assert run_jobs([], 2, pool=pool) == []
    with pytest.raises(RuntimeError):
        pool.executor.submit(os.getpid)
