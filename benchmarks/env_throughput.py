"""Env throughput: the fast control path against robosuite's, and against MuJoCo's physics limit, in one run.

Targets (issue 47): `fast_over_robosuite` >= 3.0 (low-dim env steps/s of the fast path over robosuite's
path) and `fraction_of_physics_limit` >= 0.6 (fast-path env steps/s over the rate of bare `mj_step` calls
divided by the substeps per control step), all measured here, in interleaved rounds so that machine noise
hits every rate alike. Also rgb (agentview) steps/s on both paths and the reset time.
Prints one JSON object on its last line.

    python benchmarks/env_throughput.py [--suite libero_object] [--task 0] [--steps 300] [--rounds 3]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from base_suites import make_env


def _rate(step, actions) -> float:
    start = time.perf_counter()
    for a in actions:
        step(a)
    return len(actions) / (time.perf_counter() - start)


def _physics_limit(env, steps: int) -> tuple[float, int]:
    """(bare `mj_step` calls per second from the env's current state, physics substeps per control step)."""
    import mujoco

    model, data = env.domain.sim.model._model, env.domain.sim.data._data
    substeps = int(env.domain.control_timestep / env.domain.model_timestep)
    saved = env.get_sim_state()
    start = time.perf_counter()
    for _ in range(steps * substeps):
        mujoco.mj_step(model, data)
    rate = steps * substeps / (time.perf_counter() - start)
    env.set_sim_state(saved)
    return rate, substeps


def main() -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suite", default="libero_object")
    parser.add_argument("--task", type=int, default=0)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--rgb-steps", type=int, default=60)
    args = parser.parse_args()
    actions = np.random.default_rng(0).uniform(-0.3, 0.3, size=(args.steps, 7))
    envs = {p: make_env(args.suite, args.task, init_state=0, max_steps=10**9, physics=p) for p in ("robosuite", "fast")}
    rates: dict[str, list[float]] = {"robosuite": [], "fast": [], "mj_step": []}
    for _ in range(args.rounds):  # interleaved, so machine noise hits every rate alike
        for physics, env in envs.items():
            env.reset(seed=0)
            rates[physics].append(_rate(env.step, actions))
        envs["fast"].reset(seed=0)
        mj_rate, substeps = _physics_limit(envs["fast"], args.steps)
        rates["mj_step"].append(mj_rate)
    resets = []
    for i in range(5):
        start = time.perf_counter()
        envs["fast"].reset(options={"init_state": i})
        resets.append(time.perf_counter() - start)
    for env in envs.values():
        env.close()
    rgb = {}
    for physics in ("robosuite", "fast"):
        env = make_env(args.suite, args.task, init_state=0, obs="rgb", max_steps=10**9, physics=physics)
        rgb[physics] = _rate(env.step, actions[: args.rgb_steps])
        env.close()
    median = {k: float(np.median(v)) for k, v in rates.items()}
    limit = median["mj_step"] / substeps
    result = {
        "benchmark": "env_throughput",
        "task": f"{args.suite}/{args.task}",
        "rounds": args.rounds,
        "steps_per_round": args.steps,
        "robosuite_steps_per_s": round(median["robosuite"], 1),
        "fast_steps_per_s": round(median["fast"], 1),
        "fast_over_robosuite": round(median["fast"] / median["robosuite"], 3),
        "target_fast_over_robosuite": 3.0,
        "mj_step_per_s": round(median["mj_step"], 1),
        "substeps_per_control_step": substeps,
        "physics_limit_steps_per_s": round(limit, 1),
        "fraction_of_physics_limit": round(median["fast"] / limit, 3),
        "target_fraction_of_physics_limit": 0.6,
        "reset_s_with_settle": round(float(np.median(resets)), 3),
        "rgb_steps_per_s": {k: round(v, 1) for k, v in rgb.items()},
    }
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
