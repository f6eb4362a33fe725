"""JITI's decision time per step against the env's step time, on the real simulator, in one run.

Target: decision overhead (JITI's time per step / env step time) <= 5% at N = 16 candidates, also in
mode "always" (re-selection at every step, the worst case). The base policy is a deterministic
callable, so candidates are the adapter's Gaussian perturbations. The critic is `critics.load(DIR)`
when --critic is given; otherwise a randomly initialised twin 256x256 Q network of the real input size
through the same run-time `Critic` class (the timing does not depend on the weights), which the output says.
Prints one JSON object on its last line.  Usage: python benchmarks/jiti_overhead.py [--steps 200]
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from annotations import TaskFeatureEncoder, task_key
from base_suites import make_env
from base_suites.rollout import run_episode
from elegant.intervention.jiti import JITI

TARGET = 0.05


def random_critic(metadata: Mapping[str, Any], seed: int = 0):
    """The run-time `critics` Critic over an untrained twin 256x256 Q network of the real input size
    (identity normalisation): the same inference path as a trained critic, whose weights do not matter here."""
    from critics import Critic, Normalization, TwinQNetwork

    torch.manual_seed(seed)
    encoder = TaskFeatureEncoder({task_key(metadata["suite"], metadata["task_index"]): metadata["state_layout"]})
    norm = Normalization(
        np.zeros(encoder.state_dim, np.float32),
        np.ones(encoder.state_dim, np.float32),
        -np.ones(7, np.float32),
        np.ones(7, np.float32),
    )
    return Critic(TwinQNetwork(encoder.dim, 7, hidden=(256, 256)), encoder, norm)


def make_policy():
    """A deterministic base policy that keeps the arm moving (so the env does real contact work)."""
    step = [0]

    def policy(obs):
        t = step[0]
        step[0] += 1
        return np.array([0.4 * np.sin(t / 9), 0.4 * np.cos(t / 11), 0.2 * np.sin(t / 7), 0.0, 0.0, 0.0, -1.0])

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
    decision = float(np.mean([d.time for d in agent.log]))
    return {
        "decision_ms": 1e3 * decision,
        "env_step_ms": 1e3 * env_time / steps,
        "overhead": decision / (env_time / steps),
        "interventions": agent.interventions,
    }


def main() -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--suite", default="libero_object")
    parser.add_argument("--task", type=int, default=0)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--candidates", type=int, default=16)
    parser.add_argument(
        "--critic", default=None, help="a critic directory (critics.load); default: random network of the real size"
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    env = make_env(args.suite, args.task, seed=0, max_steps=10**6)
    if args.critic:
        import critics

        critic, critic_desc = critics.load(args.critic), args.critic
    else:
        critic, critic_desc = random_critic(env.metadata), "untrained critics Critic, twin 256x256 (timing only)"
    settings = {
        "base": {"mode": "base"},
        "jiti": {"mode": "jiti"},  # the recipe: JITI's defaults
        "always": {"mode": "always"},
    }
    modes = {}
    for name, kw in settings.items():
        agent = JITI(make_policy(), critic, n_candidates=args.candidates, **kw)
        measure(env, agent, 20, seed=1)  # warm-up: first torch calls allocate
        modes[name] = measure(env, agent, args.steps, seed=0)
    env.close()
    worst = max(m["overhead"] for m in modes.values())
    return {
        "benchmark": "jiti_overhead",
        "suite": args.suite,
        "task": args.task,
        "steps": args.steps,
        "n_candidates": args.candidates,
        "critic": critic_desc,
        "modes": {k: {m: round(v, 5) if isinstance(v, float) else v for m, v in d.items()} for k, d in modes.items()},
        "worst_overhead": round(worst, 5),
        "target_overhead": TARGET,
        "meets_target": worst <= TARGET,
    }


if __name__ == "__main__":
    print(json.dumps(main()))
