"""JITI's effect and the base policy's quality: the whole chain at benchmark sizes, base vs always vs jiti.

Targets: the BC base policy (trained on mixed-quality demos) succeeds >= 70% per suite with ESR clearly
below success (issue 6); JITI's ESR >= 15 points above base, success at most 2 points below, with at most
40% of `always` mode's interventions (issue 7). Every episode of a task starts from the same init state
in every mode. The chain directory resumes (rerun the same command after an interruption).

    python benchmarks/jiti_effect.py --out runs/effect [--suites libero_object,libero_goal] [--demos 50]
        [--episodes 50] [--critic-steps 20000] [--policy-epochs 50] [--tasks 0,1] [--threshold 2 --threshold-mode std]
        [--chunk 8 --critic-rollouts 50 --critic-backup dataset] [--rollout-explore-at 8,16,24]
        [--critic-reward elegant --critic-value-loss bce --critic-hidden 64,64 --critic-weight-decay 0.1
         --critic-mc-weight 10 --critic-explored-fraction 0.5] [--critic-members 3] [--max-overrides 3] [--warmup
         steer] [--jiti-gate]

Prints the table per suite, then one JSON object on its last line.
"""

from __future__ import annotations

import argparse
import json

from chain_arguments import add_chain_arguments, chain_config

from critics import REWARDS
from elegant.cli import parse_indices
from elegant.intervention.config import TRIGGERS, WARMUPS
from elegant.pipeline import run_chain

TARGETS = {"base_success": 0.70, "esr_gain": 0.15, "max_success_drop": 0.02, "max_intervention_ratio": 0.40}


def verdicts(result: dict) -> dict:
    """Each target per suite, from the chain's per-suite numbers."""
    out = {}
    for suite, modes in result["per_suite"].items():
        base, jiti, always = modes["base"], modes["jiti"], modes["always"]
        ratio = (
            jiti["interventions_per_episode"] / always["interventions_per_episode"]
            if always["interventions_per_episode"]
            else None
        )
        out[suite] = {
            "base_success": base["success_rate"],
            "base_esr": base["esr"],
            "esr_gain": jiti["esr"] - base["esr"],
            "success_drop": base["success_rate"] - jiti["success_rate"],
            "intervention_ratio": ratio,
            "meets": {
                "base_success": base["success_rate"] >= TARGETS["base_success"],
                "esr_gain": jiti["esr"] - base["esr"] >= TARGETS["esr_gain"],
                "success_drop": base["success_rate"] - jiti["success_rate"] <= TARGETS["max_success_drop"],
                "intervention_ratio": ratio is not None and ratio <= TARGETS["max_intervention_ratio"],
            },
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_chain_arguments(parser)
    parser.add_argument("--critic-steps", type=int, default=20000)
    parser.add_argument("--critic-gamma", type=float, default=0.9)
    parser.add_argument("--critic-cql-weight", type=float, default=0.2)
    parser.add_argument(
        "--critic-reward", choices=REWARDS, default="segment", help="the critic's reward (see critics.load_transitions)"
    )
    parser.add_argument("--trust-radius", type=float, default=0.3)
    parser.add_argument("--threshold", type=float, default=2.0)
    parser.add_argument("--threshold-mode", choices=("absolute", "std"), default="std")
    parser.add_argument("--window", type=int, help="JITI's window in decisions (default: JITI's)")
    parser.add_argument("--trigger", choices=TRIGGERS, help="JITI's critical moment (default: JITI's, deviation)")
    parser.add_argument(
        "--critic-rollouts",
        type=int,
        default=0,
        help="exploring rollouts per task of the trained policy added to the critic's data (from the first half of "
        "the init states; every mode is then evaluated from the second half)",
    )
    parser.add_argument(
        "--rollout-explore",
        type=float,
        default=0.3,
        help="fraction of the rollouts' decisions given a random candidate",
    )
    parser.add_argument(
        "--rollout-explore-at",
        help="instead of --rollout-explore: decision steps, e.g. 8,16,24; each rollout "
        "takes a random candidate at one of them (elegant rollouts --explore-at)",
    )
    parser.add_argument("--critic-backup", default="policy", help="policy (Cal-QL's) or dataset (in-sample)")
    parser.add_argument("--critic-hidden", default="256,256", help="the critic's hidden layer widths")
    parser.add_argument("--critic-weight-decay", type=float, default=0.0)
    parser.add_argument(
        "--critic-mc-weight", type=float, default=0.0, help="weight of the Monte-Carlo regression beside TD"
    )
    parser.add_argument("--critic-value-loss", default="mse", help="mse, or bce (with --critic-reward elegant)")
    parser.add_argument(
        "--critic-explored-fraction",
        type=float,
        default=0.0,
        help="share of each batch from the rollouts' explored decisions",
    )
    parser.add_argument(
        "--max-overrides", type=int, help="JITI's budget of executed alternatives per episode (default: no limit)"
    )
    parser.add_argument(
        "--warmup",
        choices=WARMUPS,
        help="what JITI's first --window decisions execute: base (default) or steer (the critic's choice)",
    )
    parser.add_argument(
        "--candidates", type=int, help="actions JITI draws from the policy per decision (default: JITI's, 16)"
    )
    parser.add_argument(
        "--jiti-gate",
        action="store_true",
        help="validate base, JITI and always on the rollouts' starts first; run each task in the mode that helped most "
        "there (always only within 40%% of always's interventions)",
    )
    parser.add_argument(
        "--critic-members",
        type=int,
        default=1,
        help="critics trained on bootstrap resamples of the data; JITI overrides only when all prefer it",
    )
    args = parser.parse_args()
    config = chain_config(
        args,
        modes=("base", "always", "jiti"),
        critic_steps=args.critic_steps,
        critic_gamma=args.critic_gamma,
        critic_cql_weight=args.critic_cql_weight,
        critic_reward=args.critic_reward,
        trust_radius=args.trust_radius,
        threshold=args.threshold,
        threshold_mode=args.threshold_mode,
        window=args.window,
        trigger=args.trigger,
        critic_rollouts=args.critic_rollouts,
        rollout_explore=args.rollout_explore,
        critic_backup=args.critic_backup,
        rollout_explore_at=tuple(parse_indices(args.rollout_explore_at, "--rollout-explore-at"))
        if args.rollout_explore_at
        else None,
        critic_hidden=tuple(parse_indices(args.critic_hidden, "--critic-hidden")),
        critic_weight_decay=args.critic_weight_decay,
        critic_mc_weight=args.critic_mc_weight,
        critic_value_loss=args.critic_value_loss,
        critic_explored_fraction=args.critic_explored_fraction,
        critic_members=args.critic_members,
        max_overrides=args.max_overrides,
        warmup=args.warmup,
        jiti_gate=args.jiti_gate,
        candidates=args.candidates,
    )
    result = run_chain(args.out, config, workers=args.workers)
    table = verdicts(result)
    print(f"{'suite':16s} {'mode':7s} {'success':>8s} {'ESR':>6s} {'interv/ep':>10s}")
    for suite, modes in result["per_suite"].items():
        for mode, row in modes.items():
            print(
                f"{suite:16s} {mode:7s} {row['success_rate']:8.1%} {row['esr']:6.1%} "
                f"{row['interventions_per_episode']:10.1f}"
            )
    print(
        json.dumps(
            {
                "benchmark": "jiti_effect",
                "config": vars(args),
                "per_suite": result["per_suite"],
                "verdicts": table,
                "targets": TARGETS,
                "report": result["report"],
            }
        )
    )


if __name__ == "__main__":
    main()
