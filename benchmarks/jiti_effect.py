"""JITI's effect and the base policy's quality: the whole chain at benchmark sizes, base vs always vs jiti.

Targets: the BC base policy (trained on mixed-quality demos) succeeds >= 70% per suite with ESR clearly
below success (issue 6); JITI's ESR >= 15 points above base, success at most 2 points below, with at most
40% of `always` mode's interventions (issue 7). Every episode of a task starts from the same init state
in every mode. The chain directory resumes (rerun the same command after an interruption).

    python benchmarks/jiti_effect.py --out runs/effect [--recipe effect] [--suites libero_object] [--tasks 0,1]
        [--demos 50] [--episodes 50] [--critic-steps 4000] [--trust-radius 0.75] [--no-jiti-gate] [--workers 2]

The recipe (configs/effect.yaml by default) holds every setting; each option overrides one of them
(`--help` lists them all, with the recipe's stage prefixes: --policy-*, --critic-*, --rollout-*).

Prints the table per suite, then one JSON object on its last line.
"""

from __future__ import annotations

import argparse
import json

from chain_arguments import add_chain_arguments, chain_config

from base_suites.runtime.jobs import workers_from_args
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
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    add_chain_arguments(parser, recipe="effect")
    args = parser.parse_args()
    config = chain_config(args)
    if not {"base", "always", "jiti"} <= set(config.modes):
        parser.error(f"--modes {','.join(config.modes)}: the targets compare base, always and jiti")
    result = run_chain(args.out, config, workers=workers_from_args(args))
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
