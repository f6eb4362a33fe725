"""Demonstration collection: scripted experts rolled out in the real env, written as LIBERO-layout HDF5.

Episode i of a task starts from shipped init state i (mod 50), and its quality knobs come from
(seed, task, i), so a collection interrupted and resumed produces exactly the file an uninterrupted
run would have.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from annotations.dataset import Demo, DemoWriter
from annotations.format import task_key
from base_suites import get_task, make_env
from base_suites.env import LiberoEnv
from base_suites.errors import UserInputError
from base_suites.seeds import derive_seed


DEMO_HORIZON_FACTOR = 2


def dataset_attrs(env: LiberoEnv, suite: str, tasks: Sequence[int]) -> dict[str, Any]:
    """The `data` group attributes, in LIBERO's robomimic style."""
    domain = env.domain
    return {
        "env_args": {
            "env_name": "libero",
            "type": 1,
            "env_kwargs": {"suite": suite, "tasks": list(tasks), "controller": "OSC_POSE", "control_freq": 20,
                           "settle_steps": env.settle_steps, "obs": "lowdim", "hard_reset": False},
        },
        "problem_info": {"problem_name": type(domain).__name__.lower(), "domain_name": "robosuite",
                         "language_instruction": env.instruction},
        "language_instruction": env.instruction,
        "bddl_file_name": env.task.bddl_file,
    }


def collect_demos(
    suite: str,
    tasks: Sequence[int] | None,
    episodes: int,
    out: str,
    *,
    quality: str | Mapping[str, float] = "clean",
    seed: int = 0,
    resume: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """Roll out the scripted expert `episodes` times per task and write the demos file `out`.

    Returns a summary: demos written, success rate, per-knob rates, per-task success.
    """
    from tqdm import tqdm

    from base_suites.experts import EXPERT_VERSION, ScriptedExpert, knob_rates

    if episodes <= 0:
        raise UserInputError(f"--episodes must be positive, got {episodes}")
    knob_rates(quality)  # validate before any work
    specs = [get_task(suite, t) for t in (tasks if tasks is not None else range(10))]
    writer: DemoWriter | None = None
    total = len(specs) * episodes
    bar = tqdm(total=total, desc=f"demos {suite}", disable=not progress, unit="ep")
    summary: dict[str, Any] = {"out": out, "per_task": {}}
    try:
        for task_pos, spec in enumerate(specs):
            # Demos may run longer than the evaluation horizon: sloppy executions (undo, regrasp) take time.
            env = make_env(suite, spec.index, seed=seed, max_steps=DEMO_HORIZON_FACTOR * spec.default_max_steps)
            if writer is None:
                writer = DemoWriter(out, dataset_attrs(env, suite, [s.index for s in specs]), resume=resume)
            done_before = writer.count
            expert = ScriptedExpert(env, quality=quality, seed=derive_seed(seed, spec.index))
            for i in range(episodes):
                global_index = task_pos * episodes + i
                if global_index < done_before:
                    bar.update(1)
                    continue
                init = i % spec.n_init_states
                # A reset seed per (seed, task, episode): a resumed collection rebuilds the same scenes.
                reset_seed = derive_seed(seed, spec.index, i)
                obs, _ = env.reset(seed=reset_seed, options={"init_state": init})
                layout = env.fixture_layout()
                expert.reset(env.metadata, episode=i)
                record = record_episode(env, expert, obs)
                demo = Demo(
                    name="", actions=record["actions"], states=record["states"], obs=record["obs"],
                    next_obs=record["next_obs"], rewards=record["rewards"], dones=record["dones"],
                    attrs={
                        "suite": suite, "task_index": spec.index, "task_name": spec.name,
                        "language_instruction": env.instruction, "init_state_index": init, "seed": seed,
                        "episode": i, "knobs": {k: v for k, v in expert.knobs.items()},
                        "knob_events": list(expert.events), "expert_version": EXPERT_VERSION,
                        "success": record["success"], "perturbation": record["perturbation"],
                        "reset_seed": reset_seed, "fixture_layout": layout,
                    },
                )
                writer.append(demo, env.metadata["state_layout"])
                bar.update(1)
            env.close()
        path = writer.finish() if writer is not None else out
    except BaseException:
        if writer is not None:
            writer.abandon()
        raise
    finally:
        bar.close()
    from annotations.dataset import DemoFile

    with DemoFile(path) as f:
        demos = list(f)
    knobs = [d.attrs["knobs"] for d in demos]
    summary.update(
        demos=len(demos),
        success_rate=float(np.mean([d.attrs["success"] for d in demos])),
        knob_rates={k: float(np.mean([kn.get(k, False) for kn in knobs])) for k in (knobs[0] if knobs else {})},
    )
    for d in demos:
        summary["per_task"].setdefault(d.task_key, []).append(bool(d.attrs["success"]))
    summary["per_task"] = {k: float(np.mean(v)) for k, v in summary["per_task"].items()}
    return summary


def record_episode(env: LiberoEnv, policy, obs: Mapping[str, np.ndarray]) -> dict[str, Any]:
    """Run `policy` from the env's just-reset state and record what the demo format stores."""
    states, observations, next_observations, actions, rewards = [], [], [], [], []
    info: dict[str, Any] = {"success": False, "perturbation": []}
    for _ in range(env.max_steps):
        states.append(env.get_sim_state())
        observations.append(obs["state"])
        action = np.asarray(policy(obs), dtype=np.float64)
        obs, reward, terminated, truncated, info = env.step(action)
        actions.append(action)
        next_observations.append(obs["state"])
        rewards.append(reward)
        if terminated or truncated:
            break
    dones = np.zeros(len(actions), dtype=np.uint8)
    dones[-1] = 1
    return {
        "actions": np.array(actions), "states": np.array(states), "obs": np.array(observations),
        "next_obs": np.array(next_observations), "rewards": np.array(rewards, dtype=np.float32),
        "dones": dones, "success": bool(info["success"]), "perturbation": info["perturbation"],
    }
