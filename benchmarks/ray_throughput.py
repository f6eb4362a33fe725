"""Episodes per minute on Ray against the local process pool, on this machine's cores, in one run.

Collects the same scripted-expert demos with `--backend local` and `--backend ray` (both `--workers N`),
interleaved over `--rounds` rounds, and reports each backend's episodes per minute (medians), their ratio
(target: Ray at least 0.9x the local pool) and whether the files are identical. Ray is started once
before timing, as a cluster would be running; worker start-up (imports, the first env) is timed on both
backends. It also measures what scaling out costs per episode: Ray's round trip for a job that does
nothing (the scheduling overhead), and the bytes that cross the network per episode (the job there, the
recorded episode back).
Prints one JSON object on its last line.

    python benchmarks/ray_throughput.py [--suite libero_object] [--tasks 0,1] [--episodes 6] [--workers 2]
        [--rounds 2]
"""

from __future__ import annotations

import argparse
import json
import pickle
import statistics
import tempfile
import time
from pathlib import Path

from parallel_speedup import add_collection_arguments, hdf5_differences

from annotations.collect import EpisodeJob, collect_demos
from annotations.dataset import DemoFile
from base_suites.runtime.jobs import Workers, check_workers, run_jobs

TARGET = 0.9


def nothing() -> object:
    """A worker that does nothing: its jobs measure the backend's own cost."""
    return lambda job: job


def round_trip_ms(jobs: int) -> float:
    """Milliseconds per no-op job on one Ray actor, dispatch and result included (its start-up excluded)."""
    with run_jobs(nothing, list(range(jobs + 1)), Workers(1, "ray")) as results:
        next(results)  # the worker has started
        start = time.perf_counter()
        for _ in results:
            pass
    return (time.perf_counter() - start) / jobs * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_collection_arguments(parser, episodes=6)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    tasks = args.tasks
    backends = {"local": Workers(args.workers), "ray": check_workers(Workers(args.workers, "ray"))}
    episodes = len(tasks) * args.episodes
    seconds: dict[str, list[float]] = {name: [] for name in backends}
    with tempfile.TemporaryDirectory() as tmp:
        files = {}
        for r in range(args.rounds):
            for name, workers in backends.items():
                files[name] = str(Path(tmp) / f"{name}_{r}.hdf5")
                start = time.perf_counter()
                collect_demos(args.suite, tasks, files[name], episodes=args.episodes, seed=args.seed, workers=workers,
                              progress=False)  # fmt: skip
                seconds[name].append(time.perf_counter() - start)
        differences = hdf5_differences(files["local"], files["ray"])
        with DemoFile(files["ray"]) as f:
            result_bytes = statistics.median(len(pickle.dumps(demo)) for demo in f)
    per_minute = {name: 60 * episodes / statistics.median(s) for name, s in seconds.items()}
    result = {
        "benchmark": "ray_throughput",
        "suite": args.suite,
        "tasks": tasks,
        "episodes": episodes,
        "workers": args.workers,
        "rounds": args.rounds,
        "local_episodes_per_minute": round(per_minute["local"], 2),
        "ray_episodes_per_minute": round(per_minute["ray"], 2),
        "ray_over_local": round(per_minute["ray"] / per_minute["local"], 3),
        "target": TARGET,
        "identical_files": not differences,
        "differences": differences[:10],
        "seconds": {name: [round(x, 2) for x in s] for name, s in seconds.items()},
        "ray_scheduling_ms_per_job": round(round_trip_ms(200), 3),
        "job_bytes": len(pickle.dumps(EpisodeJob(0, tasks[0], 0))),
        "result_bytes_per_episode": int(result_bytes),
        "seconds_per_episode_per_worker": round(statistics.median(seconds["ray"]) * args.workers / episodes, 2),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
