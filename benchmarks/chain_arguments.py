"""The command-line options shared by the benchmarks built on the chain (`elegant.pipeline.run_chain`):
data, policy and evaluation sizes, turned into a `ChainConfig`."""

from __future__ import annotations

import argparse
from typing import Any

from base_suites.runtime.jobs import add_workers_argument
from elegant.pipeline import ChainConfig
from elegant.policies.protocol import add_policy_act_argument


def add_chain_arguments(parser: argparse.ArgumentParser) -> None:
    """The command-line options every benchmark built on the chain shares (data, policy, evaluation)."""
    parser.add_argument("--out", required=True, help="chain directory (resumable)")
    parser.add_argument("--suites", default="libero_object,libero_goal")
    parser.add_argument("--tasks", help="task indices for every suite (default: all)")
    parser.add_argument("--demos", type=int, default=50, help="mixed-quality demos per task")
    parser.add_argument("--episodes", type=int, default=50, help="evaluation episodes per task and mode")
    parser.add_argument("--policy-epochs", type=int, default=50)
    parser.add_argument(
        "--policy-modes", type=int, help="components of the BC policy's GMM head (default: train-policy's)"
    )
    parser.add_argument(
        "--successful-only", action="store_true", help="the policy clones only the demos that succeeded"
    )
    parser.add_argument(
        "--obs-noise",
        type=float,
        default=0.0,
        help="std of the noise on the policy's normalised input states in training",
    )
    parser.add_argument("--chunk", type=int, default=1, help="actions per decision of the policy (and of the critic)")
    parser.add_argument("--max-steps", type=int, help="episode horizon (default: the suites')")
    parser.add_argument("--seed", type=int, default=0)
    add_policy_act_argument(parser)
    add_workers_argument(parser)


def chain_config(args: argparse.Namespace, **fields: Any) -> ChainConfig:
    """A `ChainConfig` from the options of `add_chain_arguments`, with `fields` (modes, critic and JITI settings)
    added."""
    return ChainConfig(
        suites=tuple(args.suites.split(",")),
        tasks=tuple(int(t) for t in args.tasks.split(",")) if args.tasks else None,
        demos=args.demos,
        policy_epochs=args.policy_epochs,
        policy_modes=args.policy_modes,
        policy_successful_only=args.successful_only,
        policy_obs_noise=args.obs_noise,
        episodes=args.episodes,
        chunk=args.chunk,
        max_steps=args.max_steps,
        seed=args.seed,
        policy_act=args.policy_act,
        **fields,
    )
