"""Does the elegance critic prefer the clean expert's continuation to a knob's, from the same state?

Rolls the scripted expert clean and with each knob on, from each init state, branches the two where the
knob first changes an action, and scores each side's next WINDOW steps by their mean Q
(`continuation_pairs.py`). Target (issue 5): the clean side scores
higher in >= 80% of pairs. Prints a per-knob table, then one JSON object on its last line.

    python benchmarks/critic_pairs.py CRITIC_DIR --suite libero_object --task 0 [--knobs drop,tilt,misplace,collide]
        [--inits 0,1,2] [--window 25] [--seed 0] [--max-steps T]
"""

from __future__ import annotations

import argparse
import json
import time

from continuation_pairs import continuation_pairs, pair_preference

from base_suites.runtime.settings import index_list
from critics import load

TARGET = 0.8


def _fraction(value: float | None) -> str:
    return "-" if value is None else f"{value:6.1%}"


def _table(per_knob: dict, skipped: dict[str, int]) -> str:
    """One row per knob: pairs, inits skipped (knob never acted), clean wins, fraction, mean Q gap."""
    lines = [f"{'knob':10s} {'pairs':>5s} {'skipped':>7s} {'clean>knob':>10s} {'fraction':>8s} {'mean gap':>9s}"]
    for knob, n_skipped in skipped.items():
        row = per_knob.get(knob, {"pairs": 0, "clean_wins": 0, "clean_preferred": None, "mean_gap": None})
        gap = "-" if row["mean_gap"] is None else f"{row['mean_gap']:+9.4f}"
        fraction = _fraction(row["clean_preferred"])
        lines.append(f"{knob:10s} {row['pairs']:5d} {n_skipped:7d} {row['clean_wins']:10d} {fraction:>8s} {gap:>9s}")
    return "\n".join(lines)


def main() -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("critic", help="critic directory (from `elegant train-critic`)")
    parser.add_argument("--suite", required=True)
    parser.add_argument("--task", required=True, help="task index or name")
    parser.add_argument("--knobs", default="drop,tilt,misplace,collide")
    parser.add_argument("--inits", type=index_list, default=(0, 1, 2), help="init-state indices, e.g. 0-2")
    parser.add_argument("--window", type=int, default=25, help="steps scored after the branching step")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-steps", type=int, help="episode length cap (default: the task's horizon)")
    args = parser.parse_args()
    task = int(args.task) if args.task.isdigit() else args.task
    knobs = [k.strip() for k in args.knobs.split(",") if k.strip()]

    critic = load(args.critic)
    start = time.perf_counter()
    pairs = continuation_pairs(
        args.suite, task, knobs, args.inits, args.seed, window=args.window, max_steps=args.max_steps
    )
    report = pair_preference(critic.bind(pairs.metadata), pairs)
    print(_table(report["per_knob"], pairs.skipped), flush=True)
    result = {
        "benchmark": "critic_pairs",
        "critic": args.critic,
        "task": f"{pairs.metadata['suite']}/{pairs.metadata['task_index']}",
        "inits": args.inits,
        "window": args.window,
        "seed": args.seed,
        **report,
        "skipped": pairs.skipped,
        "branch_steps": {f"{p.knob}@{p.init}": p.branch_step for p in pairs},
        "seconds": round(time.perf_counter() - start, 1),
        "target": {"clean_preferred": TARGET},
    }
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
