"""Episodes spread over worker processes: one job per episode, results back in the parent as each finishes.

Why: an episode is a few seconds of single-threaded robosuite Python (85-110 env steps/s), so a
500-episode evaluation kept one core busy for about 20 minutes while the other idled, and benchmarks
were run by hand as two halves of a suite. Every episode here is a function of its task, its index and
the run seed only (resets zero the solver state LIBERO forgets; policies and JITI restart their random
streams from the episode's reset seed), so episodes can run in any process and in any order and the
numbers do not depend on the number of workers.

A worker is built once per process by a picklable factory (`make_worker()` returns a callable
job -> result) and keeps its env and policy between jobs, as the serial loop did: building an env costs
about 2.5 s. With `workers` 1 the same worker runs in this process, so both paths execute one piece of
code. Worker processes are started with "spawn" (MuJoCo and torch threads do not survive a fork) and
limited to one BLAS / OpenMP thread each, since the workers already fill the cores.
"""
from __future__ import annotations

import multiprocessing
import os
import pickle
import sys
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any, TypeVar

from base_suites.errors import UserInputError

Job = TypeVar("Job")
Result = TypeVar("Result")

_THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
_worker: Callable[[Any], Any] | None = None


def check_workers(workers: int) -> int:
    """Refuse a worker count below 1; more workers than cores are allowed (they only share them)."""
    if int(workers) < 1:
        raise UserInputError(f"--workers must be >= 1, got {workers}")
    return int(workers)


def check_picklable(value: Any, what: str) -> None:
    """Refuse, before any work, a value that worker processes cannot receive (a policy object defined in a
    script, a lambda): such policies run with workers=1, or are saved to a directory first."""
    try:
        pickle.dumps(value)
    except Exception as exc:  # pickling raises many types (PicklingError, TypeError, AttributeError)
        raise UserInputError(f"{what} cannot be sent to worker processes ({type(exc).__name__}); "
                             "pass it as a directory or run with workers=1") from None


def _start_worker(make_worker: Callable[[], Callable[[Any], Any]]) -> None:
    for name in _THREAD_VARIABLES:
        os.environ[name] = "1"
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)
    global _worker
    _worker = make_worker()
    if "torch" in sys.modules:  # imported by the factory (a policy, a critic): one intra-op thread
        sys.modules["torch"].set_num_threads(1)


def _run_job(job: Any) -> Any:
    assert _worker is not None, "worker used before _start_worker"
    return _worker(job)


def run_jobs(make_worker: Callable[[], Callable[[Job], Result]], jobs: Sequence[Job], workers: int = 1) -> Iterator[tuple[Job, Result]]:
    """Run every job and yield (job, result) as each finishes (in submission order with one worker).

    A job that raises stops the run: the jobs not yet started are cancelled, the running ones finish,
    and the exception is raised here. Stopping the iteration early cancels the rest the same way.
    """
    workers = check_workers(workers)
    if not jobs:
        return
    if workers == 1:
        worker = make_worker()
        try:
            for job in jobs:
                yield job, worker(job)
        finally:
            _close(worker)
        return
    check_picklable(make_worker, "the worker factory")
    pool = ProcessPoolExecutor(min(workers, len(jobs)), mp_context=multiprocessing.get_context("spawn"),
                               initializer=_start_worker, initargs=(make_worker,))
    try:
        pending: dict[Future, tuple[int, Job]] = {pool.submit(_run_job, job): (n, job) for n, job in enumerate(jobs)}
        while pending:
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in sorted(finished, key=lambda f: pending[f][0]):
                _, job = pending.pop(future)
                yield job, future.result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def in_order(results: Iterable[tuple[Job, Result]], position: Callable[[Job], int], first: int = 0) -> Iterator[tuple[Job, Result]]:
    """Re-order (job, result) pairs by `position(job)`, consecutive from `first`: for writers whose file
    layout is positional (a demos file names its episodes demo_0, demo_1, ...). Results that arrive early
    wait in memory; with jobs submitted in order, that is at most a few."""
    waiting: dict[int, tuple[Job, Result]] = {}
    expected = first
    for job, result in results:
        waiting[position(job)] = (job, result)
        while expected in waiting:
            yield waiting.pop(expected)
            expected += 1
    if waiting:
        raise RuntimeError(f"jobs at positions {sorted(waiting)} finished but position {expected} never did")


def _close(worker: Any) -> None:
    close = getattr(worker, "close", None)
    if callable(close):
        close()
