"""Episodes spread over worker processes: one job per episode, results back in the parent as each finishes.
`Workers` says where: local processes, or Ray actors on a cluster (`base_suites.runtime.ray_jobs`).

Why: an episode is a few seconds of single-threaded robosuite Python (85-110 env steps/s), so a
500-episode evaluation kept one core busy for about 20 minutes while the other idled, and benchmarks
were run by hand as two halves of a suite. Every episode here is a function of its task, its index and
the run seed only (resets zero the solver state LIBERO forgets; policies and JITI restart their random
streams from the episode's reset seed), so episodes can run in any process and in any order and the
results (all but wall-clock timings) do not depend on the number of workers.

A worker is built once per process by a picklable factory (`make_worker()` returns a callable
job -> result) and keeps its env and policy between jobs, as a serial loop would: building an env costs
about 2.5 s. It is built at its first job, so an error in building it reaches the caller like any job's
error (a user mistake as one line). With `workers` 1 the same worker runs in this process, so both
paths execute one piece of code. Every path runs with one BLAS thread and one torch thread: the
workers already fill the cores, and a reduction split over another number of threads could round
differently and flip a sampled action. Worker processes are started with "spawn" (MuJoCo and torch threads do not
survive a fork), ignore Ctrl-C (the parent stops them), and are terminated when the run stops early
(an error, a break, Ctrl-C); a worker that dies (a crash, the OOM killer) stops the run with
`BrokenProcessPool` instead of leaving it waiting. When jobs fail, the error raised is that of the
first failing job in submission order, after the results of every job before it, as a serial run
would give them.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import pickle
import signal
import sys
import traceback
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Literal, TypeVar, get_args

from base_suites.runtime.errors import UserInputError, unknown_choice

Job = TypeVar("Job")
Result = TypeVar("Result")

_THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
_factory: Callable[[], Callable[[Any], Any]] | None = None
_worker: Callable[[Any], Any] | None = None


Backend = Literal["local", "ray"]
BACKENDS: tuple[str, ...] = get_args(Backend)


@dataclass(frozen=True)
class Workers:
    """Where a command's episodes run: `count` processes side by side on this machine (backend "local"),
    or `count` Ray actors (backend "ray") on the cluster at `address` (None: a Ray started for the run on
    this machine; "auto": the cluster this machine joined with `ray start`). A run control, not a
    setting: files and numbers do not depend on it."""

    count: int = 1
    backend: Backend = "local"
    address: str | None = None

    def __post_init__(self) -> None:
        if int(self.count) < 1:
            raise UserInputError(f"--workers must be >= 1, got {self.count}")
        if self.backend not in BACKENDS:
            raise unknown_choice("backend", self.backend, BACKENDS)
        if self.address is not None and self.backend != "ray":
            raise UserInputError("--ray-address needs --backend ray")

    @property
    def in_process(self) -> bool:
        """Whether the jobs run in this process (one local worker): objects then need not be picklable."""
        return self.backend == "local" and self.count == 1


def add_workers_argument(parser: argparse.ArgumentParser, default: int = 1) -> None:
    """The `--workers`, `--backend` and `--ray-address` options of every command that runs episodes
    (read back by `workers_from_args`)."""
    parser.add_argument(
        "--workers",
        type=int,
        default=default,
        help=f"processes (or Ray actors) running episodes side by side (default: {default}); results do not "
        "depend on it",
    )
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default="local",
        help="local: processes on this machine; ray: Ray actors (pip install -e .[ray]); results do not depend on it",
    )
    parser.add_argument(
        "--ray-address",
        metavar="ADDR",
        help="with --backend ray: the cluster's HOST:PORT, or auto for the one this machine joined with "
        "`ray start` (default: start Ray on this machine)",
    )


def workers_from_args(args: argparse.Namespace) -> Workers:
    """The `Workers` the options of `add_workers_argument` name."""
    return Workers(args.workers, args.backend, args.ray_address)


def available_cores() -> int:
    """The cores this process may run on (its affinity, which a container or `taskset` may narrow)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def check_workers(workers: int | Workers) -> Workers:
    """`workers` as a `Workers` (a count means that many local processes), refusing a count below 1; more
    workers than cores are allowed (they only share them). Backend "ray" connects here, before any work,
    so that a missing extra or a wrong address is one line before anything is created."""
    workers = workers if isinstance(workers, Workers) else Workers(int(workers))
    if workers.backend == "ray":
        from base_suites.runtime.ray_jobs import connect

        connect(workers.address, workers.count)
    return workers


def check_picklable(value: Any, what: str) -> None:
    """Refuse, before any work, a value that cannot be sent to worker processes (a lambda, a local class,
    an open file): such values run with one worker."""
    try:
        pickle.dumps(value)
    except Exception as exc:  # pickling raises many types (PicklingError, TypeError, AttributeError)
        raise UserInputError(
            f"{what} cannot be sent to worker processes ({type(exc).__name__}); "
            "pass a directory, or run with --workers 1"
        ) from None


@contextmanager
def _spawned_with_one_thread() -> Iterator[None]:
    """Processes started inside inherit one-thread settings (read by BLAS, OpenMP and torch at import)."""
    saved = {name: os.environ.get(name) for name in _THREAD_VARIABLES}
    os.environ.update({name: "1" for name in _THREAD_VARIABLES})
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def _limit_torch_threads() -> None:
    torch = sys.modules.get("torch")
    if torch is not None and torch.get_num_threads() != 1:
        torch.set_num_threads(1)


def install_worker(make_worker: Callable[[], Callable[[Any], Any]]) -> None:
    """Make this process a worker: one BLAS thread (the BLAS loaded while the factory was unpickled) and
    the factory that `run_job` builds the worker from at its first job."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")
    global _factory, _worker
    _factory, _worker = make_worker, None


def _start_pool_worker(make_worker: Callable[[], Callable[[Any], Any]]) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C goes to the parent, which terminates the pool
    install_worker(make_worker)


class RemoteTraceback(Exception):
    """Where a worker's exception was raised: its traceback, chained as the cause of the re-raised error."""


def run_job(numbered: tuple[int, Any]) -> tuple[int, bool, Any]:
    """Job `numbered` = (position, job) on this process's worker: (position, True, result), or (position,
    False, (exception, its formatted traceback))."""
    global _worker
    try:
        if _worker is None:
            assert _factory is not None, "worker process used before install_worker"
            _worker = _factory()
        _limit_torch_threads()
        return numbered[0], True, _worker(numbered[1])
    except Exception as exc:
        return numbered[0], False, (exc, traceback.format_exc())


@contextmanager
def run_jobs(
    make_worker: Callable[[], Callable[[Job], Result]], jobs: Sequence[Job], workers: int | Workers = 1
) -> Iterator[Iterator[tuple[Job, Result]]]:
    """Context giving an iterator of (job, result) pairs in the order the jobs finish (submission order
    with one worker). A job's exception is raised from the iterator; leaving the context (an error, a
    break, Ctrl-C, or the end) terminates the workers, so no further job runs.

        with run_jobs(factory, jobs, workers) as results:
            for job, result in results: ...
    """
    workers = check_workers(workers)
    if workers.backend == "ray":
        from base_suites.runtime.ray_jobs import run_on_ray

        check_picklable(make_worker, "the worker factory")
        remote = run_on_ray(make_worker, jobs, workers.count, workers.address)
        try:
            yield remote
        finally:
            remote.close()
        return
    if workers.count == 1 or len(jobs) <= 1:
        serial = _serial(make_worker, jobs)
        try:
            yield serial
        finally:
            serial.close()
        return
    check_picklable(make_worker, "the worker factory")
    with _spawned_with_one_thread():  # processes start at submit: all of them inside
        pool = ProcessPoolExecutor(
            min(workers.count, len(jobs)),
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_start_pool_worker,
            initargs=(make_worker,),
        )
        futures = {pool.submit(run_job, (n, job)): n for n, job in enumerate(jobs)}
    try:
        yield _as_finished(futures, jobs)
    finally:
        processes = list((getattr(pool, "_processes", None) or {}).values())  # shutdown forgets them
        pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.terminate()  # an episode under way or queued for a worker is not waited for
        pool.shutdown(wait=True)


def _as_finished(futures: dict[Future, int], jobs: Sequence[Job]) -> Iterator[tuple[Job, Result]]:
    """Results as they finish; after a failure, only those of earlier jobs (later ones are cancelled or
    dropped), then the earliest failure."""
    failed: tuple[int, BaseException, str] | None = None
    for future in as_completed(futures):
        if future.cancelled():
            continue
        n, ok, value = future.result()
        if not ok:
            if failed is None or n < failed[0]:
                failed = (n, *value)
                for other, m in futures.items():
                    if m > n:
                        other.cancel()
        elif failed is None or n < failed[0]:
            yield jobs[n], value
    if failed is not None:
        _, exc, remote = failed
        raise exc from RemoteTraceback(remote)


def _serial(make_worker: Callable[[], Callable[[Job], Result]], jobs: Sequence[Job]) -> Iterator[tuple[Job, Result]]:
    """The jobs in this process, with one BLAS and one torch thread as in a worker (restored after)."""
    from threadpoolctl import threadpool_limits

    if not jobs:
        return
    with threadpool_limits(1, user_api="blas"):
        worker = make_worker()
        torch = sys.modules.get("torch")
        threads = torch.get_num_threads() if torch is not None else None
        _limit_torch_threads()
        try:
            for job in jobs:
                yield job, worker(job)
        finally:
            if threads is not None:
                torch.set_num_threads(threads)
            close = getattr(worker, "close", None)
            if callable(close):
                close()


def in_order(
    results: Iterable[tuple[Job, Result]], position: Callable[[Job], int], first: int = 0
) -> Iterator[tuple[Job, Result]]:
    """Re-order (job, result) pairs by `position(job)`, consecutive from `first`: for writers whose file
    layout is positional (a demos file names its episodes demo_0, demo_1, ...). A result that arrives
    before an earlier one waits in memory until that one is written; if the run stops first, it is lost
    and recomputed on resume."""
    waiting: dict[int, tuple[Job, Result]] = {}
    expected = first
    for job, result in results:
        waiting[position(job)] = (job, result)
        while expected in waiting:
            yield waiting.pop(expected)
            expected += 1
