"""Which shipped starts still stand after LIBERO's 10 settle steps on this stack (`base_suites.start_check`)?

For every task of the suites and each of its shipped init states (or the starts named by `--starts`), resets,
waits LIBERO's settle steps, and checks the BDDL init relations, falls, rises, tips and motion. Prints a
table per suite and names every start that breaks, with how; writes them to `--out` as JSON too. The
target (issue 69): 0 broken starts on the default stack.

    python benchmarks/start_check.py [--suites libero_spatial,libero_10] [--inits 50] [--out starts.json]
    python benchmarks/start_check.py --starts libero_spatial/5/0,libero_10/0/2

Prints one JSON object on its last line.
"""

from __future__ import annotations

import argparse
import json
import sys

from settle_drift import chosen_starts  # this folder's: the same --suites / --inits / --starts
from tqdm import tqdm

from base_suites import make_env, stack_record
from base_suites.start_check import check_start
from base_suites.suites import MAIN_SUITES


def run(chosen: dict[tuple[str, int], list[int]], physics: str) -> dict:
    suites: dict[str, dict] = {}
    for (suite, task), inits in tqdm(chosen.items(), desc="tasks", file=sys.stderr):
        row = suites.setdefault(suite, {"starts": 0, "broken": 0, "tasks_broken": set(), "names": {}})
        env = make_env(suite, task, seed=0, settle_steps=0, physics=physics, max_steps=10**6)
        try:
            for init in inits:
                broken = check_start(env, init)
                row["starts"] += 1
                if broken:
                    row["broken"] += 1
                    row["tasks_broken"].add(task)
                    row["names"][f"{suite}/{task}/{init}"] = [str(b) for b in broken]
        finally:
            env.close()
    for row in suites.values():
        row["tasks_broken"] = sorted(row["tasks_broken"])
    return {"stack": stack_record(render=None), "suites": suites, "broken": sum(r["broken"] for r in suites.values())}


def table(result: dict) -> str:
    stack = result["stack"]
    lines = [
        f"Shipped starts after LIBERO's 10 settle steps, MuJoCo {stack['mujoco']} ({stack['cpu_model']})",
        "",
        "| suite | starts | broken | tasks with a broken start |",
        "|---|---|---|---|",
    ]
    for suite, row in result["suites"].items():
        tasks = ", ".join(map(str, row["tasks_broken"])) or "none"
        lines.append(f"| {suite} | {row['starts']} | {row['broken']} | {tasks} |")
    for row in result["suites"].values():
        lines += [f"- {start}: {'; '.join(what)}" for start, what in row["names"].items()]
    return "\n".join(lines) + "\n"


def main() -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suites", default=",".join(MAIN_SUITES))
    parser.add_argument("--inits", type=int, default=None, help="the first N init states of each task (default all)")
    parser.add_argument("--starts", default=None, help="suite/task/init,... instead of --suites and --inits")
    parser.add_argument("--physics", default="fast", choices=("fast", "robosuite"))
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    result = run(chosen_starts(args.suites, args.inits, args.starts), args.physics)
    print(table(result))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1)
    return {
        "mujoco": result["stack"]["mujoco"],
        "broken": result["broken"],
        **{suite: {"starts": r["starts"], "broken": r["broken"]} for suite, r in result["suites"].items()},
    }


if __name__ == "__main__":
    print(json.dumps(main()))
