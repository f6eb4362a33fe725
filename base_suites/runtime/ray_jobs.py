"""Jobs on Ray actors: `base_suites.runtime.jobs.run_jobs` on a Ray cluster (docs/design.md §3.5, backends).

One actor per worker builds its worker once, from the factory put once in Ray's object store, and keeps
its env and policy between jobs, as a local worker process does; it runs with one BLAS, OpenMP and torch
thread, as they do. The driver keeps each actor busy with one job at a time and yields the results as
they finish: only the driver writes outputs. An actor lost mid-job (its process killed, its node gone) is
replaced and its job runs again on another actor, so a lost worker costs only the episode it was running
and nothing is written twice; a job that loses `MAX_LOSSES` workers stops the run, since it is then the
job that kills them. Job errors follow the local rule: the earliest failing job's error, after the
results of every job before it.

Ray is an optional extra (`pip install -e .[ray]`), imported only here.
"""

from __future__ import annotations

import logging
import os
import socket
import sys
from collections import Counter, deque
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from base_suites.runtime.errors import UserInputError

MAX_LOSSES = 3
# a Ray this run starts on this machine: a small object store (results are episode records and arrays)
LOCAL_OBJECT_STORE_BYTES = 512 * 1024**2
_PROBE_SECONDS = 5.0
_ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def _ray() -> Any:
    try:
        import ray
    except ImportError:
        raise UserInputError("--backend ray needs Ray: pip install -e .[ray]") from None
    return ray


def _probe(address: str) -> None:
    """Refuse, within seconds, an address where nothing listens: Ray itself would retry for ever."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise UserInputError(
            f"--ray-address {address!r}: expected HOST:PORT (e.g. 10.0.0.5:6379), ray://HOST:PORT or auto"
        )
    try:
        socket.create_connection((host, int(port)), timeout=_PROBE_SECONDS).close()
    except OSError as e:
        raise UserInputError(
            f"--ray-address {address}: no Ray cluster answers there ({e.strerror or e}); start one with "
            "`ray start --head`, or give --ray-address auto on a machine that joined one"
        ) from None


def connect(address: str | None, cpus: int) -> Any:
    """The `ray` module, connected: to the cluster at `address` ("auto": the one this machine joined with
    `ray start`), or to a Ray started here with `cpus` CPUs (None). Connects once per process."""
    ray = _ray()
    if ray.is_initialized():
        return ray
    if address not in (None, "auto"):
        _probe(address)
    # a Ray started here sees what this process imports (e.g. a policy's module beside a script); a
    # cluster's nodes need the project installed
    env = {**_ONE_THREAD, **({"PYTHONPATH": os.pathsep.join(p for p in sys.path if p)} if address is None else {})}
    try:
        ray.init(
            address=address,
            num_cpus=cpus if address is None else None,
            object_store_memory=LOCAL_OBJECT_STORE_BYTES if address is None else None,
            include_dashboard=False,
            log_to_driver=False,
            logging_level=logging.WARNING,
            runtime_env={"env_vars": env},
        )
    except ConnectionError as e:
        raise UserInputError(f"--ray-address {address}: {str(e).splitlines()[0]}") from None
    return ray


class JobActor:
    """A Ray actor holding one worker (`make_worker()`), built at its first job."""

    def __init__(self, make_worker: Callable[[], Callable[[Any], Any]]) -> None:
        from base_suites.runtime.jobs import install_worker

        install_worker(make_worker)

    def run(self, numbered: tuple[int, Any]) -> tuple[int, bool, Any]:
        from base_suites.runtime.jobs import run_job

        return run_job(numbered)


def run_on_ray(
    make_worker: Callable[[], Callable[[Any], Any]], jobs: Sequence[Any], count: int, address: str | None
) -> Iterator[tuple[Any, Any]]:
    """(job, result) pairs as the jobs finish on `count` actors of the Ray at `address` (see `connect`);
    the actors are killed when the iterator is closed (the end, an error, a break)."""
    from base_suites.runtime.jobs import RemoteTraceback

    if not jobs:
        return
    ray = connect(address, count)
    lost_errors = (ray.exceptions.RayActorError, ray.exceptions.WorkerCrashedError)
    actor_class = ray.remote(num_cpus=1, max_restarts=0)(JobActor)
    factory = ray.put(make_worker)  # sent once; each actor reads it from the object store
    actors: list[Any] = []

    def new_actor() -> Any:
        actors.append(actor_class.remote(factory))
        return actors[-1]

    pending = deque(range(len(jobs)))
    idle = [new_actor() for _ in range(min(count, len(jobs)))]
    running: dict[Any, tuple[Any, int]] = {}
    losses: Counter[int] = Counter()
    failed: tuple[int, BaseException, str] | None = None

    def needed(m: int) -> bool:  # after a failure, only the jobs before it still count
        return failed is None or m < failed[0]

    try:
        while pending or any(needed(m) for _, m in running.values()):
            while idle and pending:
                actor, n = idle.pop(), pending.popleft()
                running[actor.run.remote((n, jobs[n]))] = (actor, n)
            (ref,), _ = ray.wait(list(running), num_returns=1)
            actor, n = running.pop(ref)
            try:
                _, ok, value = ray.get(ref)
            except lost_errors as e:
                losses[n] += 1
                if losses[n] >= MAX_LOSSES:
                    raise RuntimeError(f"job {n} ({jobs[n]!r}) lost {MAX_LOSSES} Ray workers: {e}") from None
                ray.kill(actor)
                pending.appendleft(n)
                idle.append(new_actor())
                continue
            idle.append(actor)
            if not needed(n):
                continue
            if not ok:
                failed = (n, *value)
                pending = deque(m for m in pending if m < n)
            else:
                yield jobs[n], value
        if failed is not None:
            _, exc, remote = failed
            raise exc from RemoteTraceback(remote)
    finally:
        for actor in actors:
            ray.kill(actor)
