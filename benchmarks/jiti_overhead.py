"""JITI's decision time against the env's step time, on the real simulator, in one run.

Target: every mode's decision overhead (time spent deciding per env step / the env's step time) <= 5%
with N = 16 candidates. Measured for the recipe (`--chunk`, default `BCConfig`'s 8: a decision commits to
a chunk of actions, and the critic scores chunks of that length) and for a per-step policy (chunk 1, a
decision every step: the worst case, reported beside it). The base policy is deterministic and its
candidates are Gaussian perturbations of its plan; the critic is `critics.load(DIR)` when --critic is
given, otherwise an untrained twin critic of the recipe's width (`TrainConfig`'s hidden layers) and the
real input size through the same run-time `Critic` class (the timing does not depend on the weights).
Prints one JSON object on its last line.  Usage: python benchmarks/jiti_overhead.py [--steps 200]
"""

from __future__ import annotations

import argparse
import json
from collections import deque
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from annotations import TaskFeatureEncoder, task_key
from base_suites import make_env
from base_suites.rollout import run_episode
from critics.config import TrainConfig
from elegant.intervention.jiti import JITI
from elegant.policies.bc_config import BCConfig
from elegant.policies.protocol import ExecutesPlans

TARGET = 0.05


def random_critic(metadata: Mapping[str, Any], chunk: int, hidden: list[int], seed: int = 0):
    """The run-time `critics` Critic over an untrained twin Q network of the real input size scoring
    chunks of `chunk` actions (identity normalisation): the same inference path as a trained critic,
    whose weights do not matter here."""
    from critics import Critic, Normalization, TwinQNetwork

    torch.manual_seed(seed)
    encoder = TaskFeatureEncoder({task_key(metadata["suite"], metadata["task_index"]): metadata["state_layout"]})
    norm = Normalization(
        np.zeros(encoder.state_dim, np.float32),
        np.ones(encoder.state_dim, np.float32),
        -np.ones(7, np.float32),
        np.ones(7, np.float32),
    )
    return Critic(TwinQNetwork(encoder.dim, 7 * chunk, hidden=hidden), encoder, norm, {"chunk": chunk})


def sweep(t: int) -> np.ndarray:
    """The base policy's action at step t: a sweep that keeps the arm moving (real contact work)."""
    return np.array([0.4 * np.sin(t / 9), 0.4 * np.cos(t / 11), 0.2 * np.sin(t / 7), 0.0, 0.0, 0.0, -1.0])


class SweepPlans(ExecutesPlans):
    """A deterministic `ChunkedPolicy` over `sweep`: plans of `chunk` actions, candidates its plan plus
    Gaussian perturbations (as the adapter draws them for a per-step policy)."""

    def __init__(self, chunk: int, seed: int = 0) -> None:
        self.chunk, self._queue, self._t = chunk, deque(), 0
        self.rng = np.random.default_rng(seed)

    def reset(self, metadata=None, *, seed=None) -> None:
        self._queue.clear()
        if seed is not None:
            self.rng = np.random.default_rng(seed)

    def observe(self, obs) -> None:
        self._t += 1

    def plan(self, obs) -> np.ndarray:
        self._t += 1
        return np.stack([sweep(self._t + i) for i in range(self.chunk)])

    def sample_plans(self, obs, n: int) -> np.ndarray:
        plan = np.stack([sweep(self._t + i) for i in range(self.chunk)])
        return np.clip(plan + self.rng.normal(0.0, 0.1, size=(n, self.chunk, 7)), -1.0, 1.0)

    def sample(self, obs, n: int) -> np.ndarray:
        return self.sample_plans(obs, n)[:, 0]


def make_policy(chunk: int):
    """The base policy: a per-step callable for chunk 1, else a `SweepPlans`."""
    if chunk > 1:
        return SweepPlans(chunk)
    step = [0]

    def policy(obs):
        step[0] += 1
        return sweep(step[0])

    return policy


def measure(env, agent: JITI, steps: int, seed: int) -> dict[str, float]:
    """`steps` decisions of `agent` through `run_episode`, starting a new episode whenever one ends."""
    obs, _ = env.reset(seed=seed, options={"init_state": 0})
    agent.reset(env.metadata, seed=seed)
    env_time, taken = 0.0, 0
    while taken < steps:
        run = run_episode(env, agent, obs, max_steps=steps - taken)
        env_time, taken = env_time + run.env_time, taken + run.steps
        if run.terminated or run.truncated:
            obs, _ = env.reset(seed=seed)
        else:
            obs = run.obs
    decisions = [d.time for d in agent.log]
    return {
        "decision_ms": 1e3 * float(np.mean(decisions)),
        "decisions": len(decisions),
        "env_step_ms": 1e3 * env_time / steps,
        "overhead": float(np.sum(decisions)) / env_time,  # time deciding per step over the step's time
        "interventions": agent.interventions,
    }


def main() -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--suite", default="libero_object")
    parser.add_argument("--task", type=int, default=0)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--candidates", type=int, default=16)
    parser.add_argument("--chunk", type=int, default=BCConfig().chunk, help="the recipe's actions per decision")
    parser.add_argument(
        "--critic", default=None, help="a critic directory (critics.load); default: random network of the real size"
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    env = make_env(args.suite, args.task, seed=0, max_steps=10**6)
    hidden = list(TrainConfig().hidden)
    results: dict[str, dict[str, Any]] = {}
    for setting, chunk in (("recipe", args.chunk), ("per_step", 1)):
        if args.critic:
            import critics

            critic, critic_desc = critics.load(args.critic), args.critic
        else:
            critic = random_critic(env.metadata, chunk, hidden)
            critic_desc = f"untrained critics Critic, twin {'x'.join(map(str, hidden))} (timing only)"
        modes = {}
        for mode in ("base", "jiti", "always"):  # jiti: the recipe's settings, JITI's defaults
            agent = JITI(make_policy(chunk), critic, n_candidates=args.candidates, mode=mode)
            measure(env, agent, 20, seed=1)  # warm-up: first calls allocate
            modes[mode] = measure(env, agent, args.steps, seed=0)
        results[setting] = {
            "chunk": chunk,
            "critic": critic_desc,
            "modes": {
                k: {m: round(v, 5) if isinstance(v, float) else v for m, v in d.items()} for k, d in modes.items()
            },
            "worst_overhead": round(max(m["overhead"] for m in modes.values()), 5),
        }
    env.close()
    worst = results["recipe"]["worst_overhead"]
    return {
        "benchmark": "jiti_overhead",
        "suite": args.suite,
        "task": args.task,
        "steps": args.steps,
        "n_candidates": args.candidates,
        **results,
        "target_overhead": TARGET,
        "meets_target": worst <= TARGET,
        "per_step_meets_target": results["per_step"]["worst_overhead"] <= TARGET,
    }


if __name__ == "__main__":
    print(json.dumps(main()))
