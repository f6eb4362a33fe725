"""Scripted-expert success per task over shipped init states, and demos per minute on this machine.

Target (clean execution): >= 90% per suite over the 50 init states, >= 70% on every task.
Usage: python benchmarks/expert_success.py --suites libero_object,libero_spatial [--inits 50] [--quality clean]
Prints a table per task, then one JSON object on its last line.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from base_suites import list_tasks, make_env
from base_suites.experts import ScriptedExpert, parse_quality
from base_suites.rollout import run_episode
from base_suites.runtime.settings import index_list


def run_task(suite: str, index: int, inits: int, quality, seed: int) -> dict:
    env = make_env(suite, index, seed=seed)
    expert = ScriptedExpert(env, quality=quality, seed=seed)
    successes, steps = [], 0
    start = time.perf_counter()
    for i in range(inits):
        obs, _ = env.reset(options={"init_state": i % env.task.n_init_states})
        expert.reset(env.metadata, episode=i)
        run = run_episode(env, expert, obs)
        steps += run.steps
        successes.append(bool(run.info["success"]))
    env.close()
    seconds = time.perf_counter() - start
    return {
        "task": f"{suite}/{index}",
        "success": float(np.mean(successes)),
        "episodes": inits,
        "seconds": seconds,
        "steps": steps,
    }


def main() -> dict:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--suites", default="libero_object,libero_spatial,libero_goal,libero_10")
    parser.add_argument("--tasks", type=index_list, help="task indices, e.g. 0-4 or 0,3 (default: all)")
    parser.add_argument("--inits", type=int, default=50)
    parser.add_argument("--quality", default="clean")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    quality = parse_quality(args.quality)
    rows = []
    for suite in args.suites.split(","):
        indices = list(args.tasks) if args.tasks else [t.index for t in list_tasks(suite)]
        for index in indices:
            row = run_task(suite, index, args.inits, quality, args.seed)
            rows.append(row)
            print(
                f"{row['task']:22s} success {row['success']:6.1%}  ({row['episodes']} eps, {row['seconds']:.0f} s)",
                flush=True,
            )
    per_suite = {}
    for row in rows:
        per_suite.setdefault(row["task"].split("/")[0], []).append(row["success"])
    total_s = sum(r["seconds"] for r in rows)
    result = {
        "benchmark": "expert_success",
        "quality": args.quality,
        "per_task": {r["task"]: round(r["success"], 3) for r in rows},
        "per_suite": {s: round(float(np.mean(v)), 3) for s, v in per_suite.items()},
        "min_task": round(min(r["success"] for r in rows), 3),
        "demos_per_minute": round(60 * sum(r["episodes"] for r in rows) / total_s, 2),
        "env_steps_per_s": round(sum(r["steps"] for r in rows) / total_s, 1),
        "targets": {"per_suite": 0.9, "per_task": 0.7},
    }
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
