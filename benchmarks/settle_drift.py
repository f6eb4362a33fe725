"""Do LIBERO's shipped starts settle alike under two MuJoCo releases? Record, then compare.

`record` resets every task of the suites to each shipped init state with no settle steps, runs `--steps`
steps of LIBERO's dummy action (arm still, gripper open), and saves every task object's final position and
tilt with the stack it ran on. Run it once per MuJoCo release, e.g. with another release put in front of
the installed one (`pip install --no-deps --target /opt/mj/2.3.7 mujoco==2.3.7`, then
`PYTHONPATH=/opt/mj/2.3.7 python benchmarks/settle_drift.py record ...`). `compare REFERENCE OTHER...`
counts, per suite, the starts where some object ends more than 1 cm or 0.1 rad away from the reference's
and names them, marking those where MuJoCo reported an unstable simulation (a NaN or huge acceleration,
after which it resets the data and the objects jump to the XML's defaults) under either release. The
issue's target: 0 such starts on the default stack against LIBERO's own physics.

    python benchmarks/settle_drift.py record --suites libero_spatial,libero_object --out drift-3.14.json
    python benchmarks/settle_drift.py compare drift-2.3.7.json drift-3.14.json [--out table.md]

Prints one JSON object on its last line.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from tqdm import tqdm

from base_suites import SETTLE_ACTION, make_env, stack_record
from base_suites.suites import MAIN_SUITES, list_tasks

POSITION_TOL = 0.01  # m: the "moved" threshold
TILT_TOL = 0.1  # rad


def _unstable_marks(env) -> tuple[int, float]:
    """(how often MuJoCo has found a NaN, infinite or huge acceleration, simulated time). On such a finding
    MuJoCo resets the data to the model's defaults (the objects jump to where the XML puts them), which
    older releases do without keeping the count, but every release sets the time back to 0."""
    import mujoco

    data = env.domain.sim.data._data
    return int(data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number), float(data.time)


def record(chosen: dict[tuple[str, int], list[int]], steps: int, physics: str) -> dict:
    """{stack, steps, starts: {"suite/task/init": {object: [x, y, z, tilt]}}, unstable: [starts where MuJoCo
    reported an unstable simulation]}."""
    starts: dict[str, dict[str, list[float]]] = {}
    unstable = []
    for (suite, task), inits in tqdm(chosen.items(), desc="tasks", file=sys.stderr):
        env = make_env(suite, task, seed=0, settle_steps=0, physics=physics, max_steps=10**6)
        try:
            for init in inits:
                env.reset(seed=init, options={"init_state": init})
                count, time = _unstable_marks(env)
                for _ in range(steps):
                    env.step(SETTLE_ACTION)
                key = f"{suite}/{task}/{init}"
                starts[key] = {
                    name: [*map(float, env.sim.position(name)), env.sim.tilt(name)] for name in env.sim.objects
                }
                count_after, time_after = _unstable_marks(env)
                if count_after > count or time_after <= time:
                    unstable.append(key)
        finally:
            env.close()
    return {
        "stack": stack_record(render=None),
        "steps": steps,
        "physics": physics,
        "starts": starts,
        "unstable": unstable,
    }


def chosen_starts(suites: str, inits: int | None, starts: str | None) -> dict[tuple[str, int], list[int]]:
    """(suite, task) -> init states, from `--starts suite/task/init,...` or from `--suites` and `--inits`."""
    chosen: dict[tuple[str, int], list[int]] = {}
    if starts:
        for item in starts.split(","):
            suite, task, init = item.rsplit("/", 2)
            chosen.setdefault((suite, int(task)), []).append(int(init))
        return chosen
    for suite in suites.split(","):
        for task in list_tasks(suite):
            chosen[(suite, task.index)] = list(range(min(inits or task.n_init_states, task.n_init_states)))
    return chosen


def compare(reference: dict, other: dict) -> dict:
    """Per suite: starts compared, starts moved beyond the tolerances, the largest distance and tilt change,
    and every moved start with its worst object."""
    shared = sorted(set(reference["starts"]) & set(other["starts"]))
    unstable = {"reference": set(reference.get("unstable", [])), "other": set(other.get("unstable", []))}
    suites: dict[str, dict] = {}
    for key in shared:
        suite = key.rsplit("/", 2)[0]
        row = suites.setdefault(
            suite,
            {"starts": 0, "moved": 0, "moved_stable": 0, "max_distance": 0.0, "max_tilt": 0.0, "names": []},
        )
        row["starts"] += 1
        worst = None
        for name, ref in reference["starts"][key].items():
            got = other["starts"][key][name]
            distance = float(np.linalg.norm(np.subtract(got[:3], ref[:3])))
            tilt = abs(got[3] - ref[3])
            row["max_distance"] = max(row["max_distance"], distance)
            row["max_tilt"] = max(row["max_tilt"], tilt)
            if (distance > POSITION_TOL or tilt > TILT_TOL) and (worst is None or distance > worst[1]):
                worst = (name, distance, tilt)
        if worst is not None:
            row["moved"] += 1
            blew_up = [side for side in ("reference", "other") if key in unstable[side]]
            row["moved_stable"] += not blew_up
            note = f" (unstable under {' and '.join(blew_up)})" if blew_up else ""
            row["names"].append(f"{key} {worst[0]} {100 * worst[1]:.1f} cm {worst[2]:.3f} rad{note}")
    return {
        "reference": reference["stack"],
        "other": other["stack"],
        "suites": suites,
        "moved": sum(r["moved"] for r in suites.values()),
        "moved_stable": sum(r["moved_stable"] for r in suites.values()),
        "unstable": {side: len(keys & set(shared)) for side, keys in unstable.items()},
        "starts": len(shared),
    }


def table(result: dict) -> str:
    ref, other = result["reference"]["mujoco"], result["other"]["mujoco"]
    lines = [
        f"MuJoCo {other} against {ref}: starts whose objects end > 1 cm or > 0.1 rad apart",
        "",
        "| suite | starts | moved | moved, both stable | largest distance (cm) | largest tilt change (rad) |",
        "|---|---|---|---|---|---|",
    ]
    for suite, row in result["suites"].items():
        lines.append(
            f"| {suite} | {row['starts']} | {row['moved']} | {row['moved_stable']} | "
            f"{100 * row['max_distance']:.2f} | {row['max_tilt']:.3f} |"
        )
    for row in result["suites"].values():
        lines += [f"- {name}" for name in row["names"]]
    return "\n".join(lines) + "\n"


def main() -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    rec = sub.add_parser("record")
    rec.add_argument("--suites", default=",".join(MAIN_SUITES))
    rec.add_argument("--steps", type=int, default=40)
    rec.add_argument("--inits", type=int, default=None, help="the first N init states of each task (default all)")
    rec.add_argument("--starts", default=None, help="suite/task/init,... instead of --suites and --inits")
    rec.add_argument("--physics", default="fast", choices=("fast", "robosuite"))
    rec.add_argument("--out", required=True)
    cmp_ = sub.add_parser("compare")
    cmp_.add_argument("reference")
    cmp_.add_argument("others", nargs="+")
    cmp_.add_argument("--out", default=None, help="also write the tables as Markdown")
    args = parser.parse_args()
    if args.command == "record":
        start = time.perf_counter()
        result = record(chosen_starts(args.suites, args.inits, args.starts), args.steps, args.physics)
        with open(args.out, "w") as f:
            json.dump(result, f)
        summary = {"out": args.out, "starts": len(result["starts"]), "seconds": round(time.perf_counter() - start)}
        summary["stack"] = result["stack"]
        return summary
    with open(args.reference) as f:
        reference = json.load(f)
    results, text = [], ""
    for path in args.others:
        with open(path) as f:
            results.append(compare(reference, json.load(f)))
        text += table(results[-1]) + "\n"
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text)
    return {r["other"]["mujoco"]: {k: r[k] for k in ("starts", "moved", "moved_stable", "unstable")} for r in results}


if __name__ == "__main__":
    print(json.dumps(main()))
