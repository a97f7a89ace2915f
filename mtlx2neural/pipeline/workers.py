"""Where the per-material jobs run: in this process, a local process pool, or Ray.

Training one material is independent of training another, so every material is
one :class:`MaterialJob`, run by one function, :func:`run_job`, wherever it runs:

- ``workers=1``: in this process, one after another, with a progress bar each;
- ``workers=N`` (N > 1): a local ``ProcessPoolExecutor`` with the ``spawn`` context. A worker
  process that dies (a native library's ``exit()``, a crash, a kill) fails only its own
  material: the jobs its broken pool still held run again, each in a process of its own
  (:func:`_run_pool`).
  Each worker gets ``cpus // N`` torch threads (at least 1), set both through
  ``OMP_NUM_THREADS``/``MKL_NUM_THREADS`` at spawn time and ``torch.set_num_threads``:
  torch's OpenMP kernels collapse (100x) when more threads than free cores compete
  (BENCHMARKS.md, "Reference BRDF throughput"). Workers send their progress through a queue, and the parent
  draws one bar per material (phase, loss, ETA) and prints a line per finished one;
- ``workers="ray"`` (a local Ray cluster, or the one ``RAY_ADDRESS`` names) or
  ``"ray://host:port"`` (Ray client): the same :func:`run_job` as Ray tasks, with
  ``num_cpus=1`` and ``num_gpus=1`` when the cluster has GPUs (the task then trains
  on ``cuda``). Needs the optional extra: ``pip install mtlx2neural[ray]``. Through
  ``ray://`` the worker trains in a temporary folder and the files come back with
  the result; texture paths must resolve on the workers too (a shared file system,
  or the same paths), and the workers need mtlx2neural installed.

A job carries its MaterialX document as XML (documents do not pickle) and writes its
results into its material folder (``checkpoint.pt``, ``training_curves.csv``,
``summary.json``, PNGs: :func:`~mtlx2neural.pipeline.material_training.train_material`). With an error budget
(``max_error``) it trains decoders from small to large until the HDR FLIP meets the
budget (:func:`~mtlx2neural.pipeline.budget.choose_decoder`).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import os
from collections.abc import Callable
from pathlib import Path

import torch

from mtlx2neural.errors import InputError, write_failure
from mtlx2neural.material_record import MaterialRecord
from mtlx2neural.pipeline.devices import resolve_device
from mtlx2neural.pipeline.jobs import (
    MaterialJob,
    Shipped,
    init_pool_worker,
    pool_worker_started,
    run_job,
)
from mtlx2neural.progress import progress_bar
from mtlx2neural.train.row_process import spawn_threads
from mtlx2neural.train.trainer import TrainingInterrupted


def available_cpus() -> int:
    try:
        return len(os.sched_getaffinity(0)) or 1
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def default_workers(n_jobs: int, device: str) -> int:
    """min(jobs, CPUs) on the CPU; min(jobs, GPUs) on CUDA (one GPU per worker)."""
    device = resolve_device(device)
    if device.startswith("cuda"):
        return max(1, min(n_jobs, torch.cuda.device_count() if device == "cuda" else 1))
    return max(1, min(n_jobs, available_cpus()))


def parse_workers(value) -> int | str | None:
    """``None``/``"auto"`` (None), a positive integer, ``"ray"`` or ``"ray://host:port"``; else ValueError."""
    if value is None or value == "auto":
        return None
    if isinstance(value, int) or (isinstance(value, str) and value.strip().isdigit()):
        n = int(value)
        if n < 1:
            raise ValueError(f"--workers must be at least 1 (got {n})")
        return n
    if value == "ray" or (isinstance(value, str) and value.startswith("ray://") and len(value) > 6):
        return value
    raise ValueError(f"--workers {value!r}: give a number of processes, 'ray' (a local Ray cluster, or "
                     f"$RAY_ADDRESS) or 'ray://HOST:PORT'")


Report = Callable[[int, dict], None]
"""Called in the parent as each job finishes: (job index, its record)."""
Failed = Callable[[int, BaseException], None]
"""Called in the parent for each job whose training raised: (job index, the error)."""


def _interrupt(exc: BaseException) -> bool:
    """Is ``exc`` a stop of the whole run (Ctrl-C in a worker), never a per-material failure?"""
    return isinstance(exc, (TrainingInterrupted, KeyboardInterrupt, SystemExit))


def _settle(errors: list[tuple[int, BaseException]], failed: Failed | None, jobs) -> None:
    """After every job ran: re-raise an interrupt, or a failure to write (a full disk:
    :func:`~mtlx2neural.errors.write_failure`, an ``OSError`` naming the job's folder, never a
    material's failure), else report each failure through ``failed`` (None: raise the first)."""
    for _, exc in errors:
        if _interrupt(exc):
            raise exc
    for i, exc in errors:
        disk = write_failure(exc, getattr(jobs[i], "folder", ""))
        if disk is not None:
            raise disk from exc
    if errors and failed is None:
        raise errors[0][1]
    for i, exc in errors:
        failed(i, exc)


WARM_NICE = 10
"""The ``nice`` increment of a :class:`WarmPool`'s workers: their start-up takes the CPU its parent leaves."""


class WarmPool:
    """A local pool of ``n`` spawned workers started before its jobs are known (a ``--network scene`` run
    starts its measuring processes as its training begins), so that their start-up (spawn, imports, about
    2 s each) overlaps the parent's work. They run at ``nice`` :data:`WARM_NICE`. :func:`run_jobs` given it
    (``pool=``) runs its jobs there, when it would use a pool of that size, and shuts it down; otherwise,
    :meth:`close` it."""

    def __init__(self, n: int):
        import multiprocessing

        self.n, self.threads = n, max(1, available_cpus() // n)
        with spawn_threads(self.threads):
            self.executor = _executor(n, self.threads, multiprocessing.get_context("spawn"), WARM_NICE)
            for _ in range(n):  # the executor starts a process per job while none is idle: all n now
                self.executor.submit(pool_worker_started)

    def close(self) -> None:
        self.executor.shutdown(wait=True, cancel_futures=True)


def run_jobs(jobs: list[MaterialJob], workers, report: Report | None = None,
             failed: Failed | None = None, pool: WarmPool | None = None) -> list[MaterialRecord | None]:
    """Run every job of ``jobs`` with ``workers`` (see the module docstring); summaries in job order.

    When jobs fail (any ``Exception`` their training raises: a non-finite loss, out of
    memory, an error in a worker process or Ray task), the others still run to the end
    (their results are saved and cached). Then, with ``failed``, each failure is passed to
    it and its record is None; without, the first failure is raised. Ctrl-C stops every
    job at a checkpoint and raises :class:`~mtlx2neural.train.trainer.TrainingInterrupted`
    (never a per-material failure). ``pool``: a :class:`WarmPool` to run a local pool's jobs in (closed here
    either way).
    """
    try:
        return _run_jobs(jobs, workers, report, failed, pool)
    finally:
        if pool is not None:
            pool.close()


def _run_jobs(jobs, workers, report, failed, pool):
    workers = parse_workers(workers)
    if not jobs:
        return []
    if isinstance(workers, str):
        return _run_ray(jobs, workers, report, failed)
    n = workers or default_workers(len(jobs), jobs[0].device)
    if n == 1 or len(jobs) == 1:
        out: list[MaterialRecord | None] = []
        errors: list[tuple[int, BaseException]] = []
        for i, job in enumerate(jobs):
            try:
                out.append(run_job(job))
            except TrainingInterrupted:
                raise
            except Exception as exc:  # noqa: BLE001 - one material's failure; the others still train
                if failed is None:
                    raise
                out.append(None)
                errors.append((i, exc))
                continue
            if report:
                report(i, out[-1])
        _settle(errors, failed, jobs)
        return out
    return _run_pool(jobs, n, report, failed, pool)


class WorkerDied(RuntimeError):
    """The process training a material ended without an answer (a native library's ``exit()`` or
    ``abort()``, a crash, a kill): that material's failure, never the others'."""


def _run_pool(jobs, n: int, report, failed: Failed | None = None,
              pool: WarmPool | None = None) -> list[MaterialRecord | None]:
    """Run ``jobs`` in a pool of ``n`` spawned processes. A process that dies breaks the pool and
    with it every job the pool still held, so those jobs run again, each in a process of its own
    (``n`` at a time): a job whose own process dies there is the one that killed its worker, and
    fails alone with :class:`WorkerDied`."""
    import multiprocessing

    n = min(n, len(jobs))
    threads = max(1, available_cpus() // n)
    devices = _pool_devices(jobs[0].device, n)
    ctx = multiprocessing.get_context("spawn")
    bars = _PoolBars(jobs, ctx) if jobs[0].progress else None
    if bars:
        what = "measuring" if jobs[0].trained is not None else "training"  # a shared network's: trained already
        materials = len({j.folder for j in jobs})  # a material measured in parts is one material
        print(f"{what} {materials} materials{f' ({len(jobs)} jobs)' if materials < len(jobs) else ''} in {n} "
              f"processes ({threads} torch thread(s) each, "
              f"{', '.join(devices)})", flush=True)
    jobs = [dataclasses.replace(j, progress=False, threads=threads, device=devices[i % len(devices)],
                                progress_queue=bars.queue if bars else None, index=i)
            for i, j in enumerate(jobs)]
    results: list[MaterialRecord | None] = [None] * len(jobs)
    errors: list[tuple[int, BaseException]] = []
    try:
        with spawn_threads(threads):
            warm = pool.executor if pool is not None and (pool.n, pool.threads) == (n, threads) else None
            broken = _pool_round(jobs, list(range(len(jobs))), n, threads, ctx, results, errors, report,
                                 executor=warm)
            if broken:
                if jobs[0].progress or bars:
                    print(f"a worker process died; training {len(broken)} material(s) it held again, each in a "
                          f"process of its own", flush=True)
                for start in range(0, len(broken), n):  # n single-process pools at a time
                    chunk = broken[start:start + n]
                    lost = _pool_round(jobs, chunk, 1, threads, ctx, results, errors, report, isolated=True)
                    errors.extend((i, WorkerDied(
                        f"the process training {jobs[i].name} ended abruptly (a native library's exit() or "
                        f"abort(), a crash, or a kill); the other materials were not affected")) for i in lost)
    finally:
        if bars:
            bars.close()
    _settle(sorted(errors, key=lambda e: e[0]), failed, jobs)
    return results


def _pool_round(jobs, indices, n, threads, ctx, results, errors, report, isolated: bool = False,
                executor=None) -> list[int]:
    """Run ``jobs[i]`` for ``i`` in ``indices`` in one pool of ``n`` processes (``isolated``: one pool
    per job; ``executor``: that pool, started already); fills ``results``/``errors``; returns the indices
    whose pool broke under them."""
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool

    pools = [executor] if executor is not None else [_executor(n, threads, ctx)
                                                     for _ in (indices if isolated else [None])]
    broken = []
    try:
        futures = {pools[k if isolated else 0].submit(run_job, jobs[i]): i for k, i in enumerate(indices)}
        for f in as_completed(futures):
            i = futures[f]
            exc = f.exception()
            if isinstance(exc, BrokenProcessPool):
                broken.append(i)
            elif exc is not None:
                errors.append((i, exc))
            else:
                results[i] = f.result()
                if report:
                    report(i, results[i])
    except KeyboardInterrupt:
        for ex in pools:
            _interrupt_workers(ex)  # a SIGTERM reached this process only; a terminal's Ctrl-C reached all
            ex.shutdown(wait=True, cancel_futures=True)  # running jobs save their checkpoints
        raise TrainingInterrupted("interrupted; finished materials and checkpoints are saved in their "
                                  "folders (rerun with --resume)") from None
    finally:
        for ex in pools:
            ex.shutdown(wait=True)
    return sorted(broken)


def _executor(n: int, threads: int, ctx, nice: int = 0):
    """A pool of ``n`` ``ctx`` processes, each with ``threads`` torch threads at ``nice``
    (:func:`~mtlx2neural.pipeline.jobs.init_pool_worker`)."""
    from concurrent.futures import ProcessPoolExecutor

    return ProcessPoolExecutor(n, mp_context=ctx, initializer=init_pool_worker, initargs=(threads, nice))


def _interrupt_workers(ex) -> None:
    """SIGINT to the pool's worker processes: each running job saves its checkpoint and stops (a worker
    acts on the first signal only, so one that had Ctrl-C from the terminal too is not cut short)."""
    import signal

    for proc in list((getattr(ex, "_processes", None) or {}).values()):  # the executor's own record
        try:
            os.kill(proc.pid, signal.SIGINT)
        except (OSError, AttributeError):
            pass


class _PoolBars:
    """One progress bar per pool job (phase, loss, ETA; log lines off a terminal: :mod:`.progress`),
    fed by the workers through a queue."""

    def __init__(self, jobs, ctx):
        import threading

        self.manager = ctx.Manager()
        self.queue = self.manager.Queue()
        self.bars = [progress_bar(j.cfg.iterations, desc=j.name.rsplit("/", 1)[-1], position=i)
                     for i, j in enumerate(jobs)]
        self.thread = threading.Thread(target=self._drain, daemon=True)
        self.thread.start()

    def _drain(self):
        while True:
            msg = self.queue.get()
            if msg is None:
                return
            i, step, total, loss, phase = msg
            bar = self.bars[i]
            bar.total = total
            bar.update(step - bar.n)
            bar.set_postfix(phase=phase, loss=f"{loss:.4f}")

    def close(self):
        self.queue.put(None)
        self.thread.join(timeout=5)
        for bar in self.bars:
            bar.close()
        self.manager.shutdown()


def _pool_devices(device: str, n: int) -> list[str]:
    device = resolve_device(device)
    if device == "cuda" and torch.cuda.device_count() > 1:
        return [f"cuda:{i}" for i in range(min(n, torch.cuda.device_count()))]
    return [device]


def check_workers(workers):
    """:func:`parse_workers`, with a bad value or a Ray runner without Ray installed an
    :class:`InputError`: checked before any work (Ray is an optional extra)."""
    try:
        workers = parse_workers(workers)
    except ValueError as exc:
        raise InputError(str(exc)) from None
    if isinstance(workers, str) and importlib.util.find_spec("ray") is None:
        raise InputError(f"--workers {workers} needs Ray: pip install 'mtlx2neural[ray]' "
                         f"(or give a number of local processes)")
    return workers


def _run_ray(jobs, address: str, report, failed: Failed | None = None) -> list[MaterialRecord | None]:
    check_workers(address)
    import ray  # local: Ray is an optional extra, imported only for a Ray runner

    started = not ray.is_initialized()
    if started:
        ray.init(address=None if address == "ray" else address, include_dashboard=False,
                 log_to_driver=False)
    try:
        gpus = jobs[0].device != "cpu" and ray.cluster_resources().get("GPU", 0) >= 1
        task = ray.remote(num_cpus=1, num_gpus=1 if gpus else 0, max_retries=0)(run_job)
        ship = address.startswith("ray://")
        if jobs[0].progress:
            print(f"training {len(jobs)} materials as Ray tasks ({'1 GPU' if gpus else '1 CPU'} each, cluster: "
                  f"{ray.cluster_resources().get('CPU', 0):g} CPUs, {ray.cluster_resources().get('GPU', 0):g} "
                  f"GPUs); one line per finished material", flush=True)
        refs = {}
        for i, j in enumerate(jobs):
            ckpt = Path(j.folder) / "checkpoint.pt"
            j = dataclasses.replace(j, progress=False, threads=1, device="cuda" if gpus else "cpu", ship=ship,
                                    checkpoint=ckpt.read_bytes() if ship and j.resume and ckpt.is_file() else None)
            refs[task.remote(j)] = i
        results: list[MaterialRecord | None] = [None] * len(jobs)
        errors, pending = [], list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            i = refs[done[0]]
            try:
                result = ray.get(done[0])
            except Exception as exc:  # noqa: BLE001 - re-raised once the others finish
                errors.append((i, getattr(exc, "cause", None) or exc))
                continue
            if isinstance(result, Shipped):
                folder = Path(jobs[i].folder)
                folder.mkdir(parents=True, exist_ok=True)
                for name, data in result.files.items():
                    (folder / name).write_bytes(data)
                result = result.record
            results[i] = result
            if report:
                report(i, result)
        _settle(sorted(errors, key=lambda e: e[0]), failed, jobs)
        return results
    finally:
        if started:
            ray.shutdown()
