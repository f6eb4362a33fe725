"""ITC monitor cost: env steps with and without the monitor, same task and actions, in one run.

The action sequence is recorded once from the scripted expert (sweeping its hand through a
distractor, then picking and placing), so the monitored steps see real contacts, grasps and
violations; both timed passes replay it from the same init state. Target: the monitor adds <= 10%
to an env step (ratio <= 1.10). Rounds alternate plain and monitored passes so machine noise hits
both alike; the monitor's own time is also measured inside the monitored loop, the steadier figure on
a shared machine.
Prints one JSON object on its last line.
Usage: python benchmarks/itc_cost.py [--suite libero_10 --task 0 --steps 250 --rounds 3]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from base_suites import make_env
from base_suites.experts import ScriptedExpert
from itc import ITCMonitor


def expert_actions(env, steps: int, seed: int) -> np.ndarray:
    """The scripted expert's actions from init state 0 with its `collide` knob on."""
    env.reset(options={"init_state": 0})
    expert = ScriptedExpert(env, quality={"collide": 1.0}, seed=seed)
    expert.reset()
    actions = []
    for _ in range(steps):
        actions.append(expert(None))
        env.step(actions[-1])
    return np.array(actions)


def plain_episode(env, actions) -> float:
    env.reset(options={"init_state": 0})
    start = time.perf_counter()
    for a in actions:
        env.step(a)
    return time.perf_counter() - start


def monitored_episode(env, monitor, actions) -> tuple[float, float, int]:
    env.reset(options={"init_state": 0})
    monitor.reset()
    in_monitor, violations = 0.0, 0
    start = time.perf_counter()
    for a in actions:
        env.step(a)
        t = time.perf_counter()
        violations += monitor.step(a).reward == 0.0
        in_monitor += time.perf_counter() - t
    return time.perf_counter() - start, in_monitor, violations


def main() -> dict:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--suite", default="libero_10")
    parser.add_argument("--task", type=int, default=0)
    parser.add_argument("--steps", type=int, default=250)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    env = make_env(args.suite, args.task, init_state=0, seed=args.seed, max_steps=10**9)
    monitor = ITCMonitor(env)
    actions = expert_actions(env, args.steps, args.seed)
    plain, monitored, inside, violations = [], [], [], 0
    for _ in range(args.rounds):
        plain.append(plain_episode(env, actions))
        total, in_monitor, violations = monitored_episode(env, monitor, actions)
        monitored.append(total)
        inside.append(in_monitor)
    plain_s, monitored_s, inside_s = float(np.median(plain)), float(np.median(monitored)), float(np.median(inside))
    result = {
        "benchmark": "itc_cost",
        "task": f"{args.suite}/{args.task}",
        "steps": args.steps,
        "plain_ms_per_step": round(1e3 * plain_s / args.steps, 3),
        "monitored_ms_per_step": round(1e3 * monitored_s / args.steps, 3),
        "monitor_ms_per_step": round(1e3 * inside_s / args.steps, 3),
        "monitored_over_plain": round(monitored_s / plain_s, 3),
        "monitor_share_of_step": round(inside_s / (monitored_s - inside_s), 3),
        "target_monitored_over_plain": 1.10,
        "steps_with_violations": int(violations),
    }
    env.close()
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
