"""Env throughput: raw LIBERO ControlEnv vs our gymnasium env on the same task and actions, in one run.

Target: wrapped low-dim steps/s >= 0.9x raw. Also reset time and rgb (agentview 128x128) steps/s.
Prints one JSON object on its last line.  Usage: python benchmarks/env_throughput.py [--steps 300]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from base_suites import get_task, make_env
from base_suites._libero import libero_modules


def _rate(step, actions) -> float:
    start = time.perf_counter()
    for a in actions:
        step(a)
    return len(actions) / (time.perf_counter() - start)


def main() -> dict:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--suite", default="libero_object")
    parser.add_argument("--task", type=int, default=0)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    actions = np.random.default_rng(0).uniform(-0.3, 0.3, size=(args.steps, 7))
    task = get_task(args.suite, args.task)
    raw = libero_modules()["env_wrapper"].ControlEnv(
        bddl_file_name=task.bddl_file,
        use_camera_obs=False,
        has_offscreen_renderer=False,
        camera_names=[],
        hard_reset=False,
        ignore_done=True,
        horizon=10**9,
    )
    init = task.load_init_states()[0]
    wrapped = make_env(args.suite, args.task, init_state=0, max_steps=10**9)

    def raw_episode():
        raw.reset()
        raw.set_init_state(init)
        return _rate(raw.step, actions)

    def wrapped_episode():
        wrapped.reset()
        return _rate(wrapped.step, actions)

    raw_rates, wrapped_rates = [], []
    for _ in range(args.rounds):  # interleaved, so machine noise hits both alike
        raw_rates.append(raw_episode())
        wrapped_rates.append(wrapped_episode())
    resets = []
    for i in range(5):
        start = time.perf_counter()
        wrapped.reset(options={"init_state": i})
        resets.append(time.perf_counter() - start)
    rgb = make_env(args.suite, args.task, init_state=0, obs="rgb", max_steps=10**9)
    rgb_rate = _rate(rgb.step, actions[:60])
    result = {
        "benchmark": "env_throughput",
        "task": f"{args.suite}/{args.task}",
        "raw_steps_per_s": round(float(np.median(raw_rates)), 1),
        "wrapped_steps_per_s": round(float(np.median(wrapped_rates)), 1),
        "wrapped_over_raw": round(float(np.median(wrapped_rates) / np.median(raw_rates)), 3),
        "target_wrapped_over_raw": 0.9,
        "reset_s_with_settle": round(float(np.median(resets)), 3),
        "rgb_steps_per_s": round(rgb_rate, 1),
    }
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
