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

import h5py
import numpy as np

from annotations.collect import collect_demos
from base_suites.runtime.settings import index_list


def hdf5_contents(path: str) -> dict[str, object]:
    """Every dataset's values and every group's and dataset's attributes of an HDF5 file, by name."""

    def attrs(obj: h5py.HLObject) -> dict:
        return {k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in obj.attrs.items()}

    out: dict[str, object] = {}
    with h5py.File(path, "r") as f:
        out["/@"] = attrs(f)

        def visit(name: str, obj: h5py.HLObject) -> None:
            out[f"{name}@"] = attrs(obj)
            if isinstance(obj, h5py.Dataset):
                out[name] = obj[()]

        f.visititems(visit)
    return out


def hdf5_differences(a: str, b: str) -> list[str]:
    """The names of the datasets and attribute sets in which two HDF5 files differ (none: identical)."""
    ca, cb = hdf5_contents(a), hdf5_contents(b)
    differ = sorted(set(ca) ^ set(cb))
    for name in sorted(set(ca) & set(cb)):
        x, y = ca[name], cb[name]
        if not (np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y):
            differ.append(name)
    return differ


def add_collection_arguments(parser: argparse.ArgumentParser, episodes: int) -> None:
    """The expert collection a worker benchmark times: --suite, --tasks, --episodes (per task), --workers,
    --seed."""
    parser.add_argument("--suite", default="libero_object")
    parser.add_argument("--tasks", default=(0, 1), type=index_list)
    parser.add_argument("--episodes", type=int, default=episodes, help="episodes per task")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_collection_arguments(parser, episodes=10)
    args = parser.parse_args()
    tasks = args.tasks
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
        identical = not hdf5_differences(files[1], files[args.workers])
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
