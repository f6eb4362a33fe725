"""How much faster episodes run on several worker processes, and that the results stay the same.

Collects the same scripted-expert demos with one worker and with `--workers N`, in this one command
(the machine is shared and noisy: only the ratio of the two timings means anything), then checks that
the two files hold identical episodes. The target on a 2-core machine is a speedup of at least 1.6x
for 20 or more episodes (worker start-up, ~5 s, is paid once per run).

    python benchmarks/parallel_speedup.py [--suite libero_object] [--tasks 0,1] [--episodes 10] [--workers 2]

Prints one JSON object on its last line.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from annotations import DemoFile
from annotations.collect import collect_demos
from elegant.cli import parse_indices


def same_episodes(a: str, b: str) -> bool:
    """Whether two demo files hold the same episodes: actions, simulator states and attributes."""
    with DemoFile(a) as fa, DemoFile(b) as fb:
        return len(fa) == len(fb) and all(
            np.array_equal(da.actions, db.actions) and np.array_equal(da.states, db.states) and da.attrs == db.attrs
            for da, db in zip(fa, fb)
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suite", default="libero_object")
    parser.add_argument("--tasks", default="0,1")
    parser.add_argument("--episodes", type=int, default=10, help="episodes per task")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    tasks = parse_indices(args.tasks, "--tasks")
    seconds, files = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for workers in (1, args.workers):
            files[workers] = str(Path(tmp) / f"demos_{workers}.hdf5")
            start = time.perf_counter()
            collect_demos(
                args.suite,
                tasks,
                files[workers],
                episodes=args.episodes,
                quality="mixed",
                seed=args.seed,
                progress=False,
                workers=workers,
            )
            seconds[workers] = time.perf_counter() - start
        identical = same_episodes(files[1], files[args.workers])
    episodes = len(tasks) * args.episodes
    print(
        f"{episodes} episodes: 1 worker {seconds[1]:.1f} s, {args.workers} workers {seconds[args.workers]:.1f} s, "
        f"speedup {seconds[1] / seconds[args.workers]:.2f}x, identical files: {identical}"
    )
    print(
        json.dumps(
            {
                "benchmark": "parallel_speedup",
                "episodes": episodes,
                "workers": args.workers,
                "serial_seconds": round(seconds[1], 2),
                "parallel_seconds": round(seconds[args.workers], 2),
                "speedup": round(seconds[1] / seconds[args.workers], 3),
                "identical": identical,
            }
        )
    )


if __name__ == "__main__":
    main()
