"""The BC base policy's quality: trained on mixed-quality expert demos, success and ESR per suite and task.

Targets (issue 6): success >= 70% per suite over `--episodes` episodes per task, with ESR clearly below
success (at least 10 points: that gap is what JITI is meant to close). The chain is `elegant.pipeline`'s
with the base mode only, so no critic is trained; its directory resumes (rerun the same command after an
interruption). Every suite's demos train one policy, with the task as a one-hot input.

    python benchmarks/policy_quality.py --out runs/policy [--recipe policy_quality] [--suites libero_object]
        [--demos 50] [--episodes 50] [--policy-epochs 150] [--tasks 0,1] [--seed 0] [--policy-obs-noise 0.1]

Prints the table per task and suite, then one JSON object on its last line.
"""

from __future__ import annotations

import argparse
import json

from chain_arguments import add_chain_arguments, chain_config

from base_suites.runtime.jobs import workers_from_args
from elegant.pipeline import run_chain

TARGETS = {"suite_success": 0.70, "esr_gap": 0.10}


def verdicts(per_suite: dict[str, dict[str, float]]) -> dict[str, dict]:
    """Each target per suite."""
    return {
        suite: {
            "success": row["success_rate"],
            "esr": row["esr"],
            "esr_gap": row["success_rate"] - row["esr"],
            "meets": {
                "suite_success": row["success_rate"] >= TARGETS["suite_success"],
                "esr_gap": row["success_rate"] - row["esr"] >= TARGETS["esr_gap"],
            },
        }
        for suite, row in per_suite.items()
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    add_chain_arguments(parser, recipe="policy_quality")
    args = parser.parse_args()
    config = chain_config(args)
    result = run_chain(args.out, config, workers=workers_from_args(args))
    suites = {suite: modes["base"] for suite, modes in result["per_suite"].items()}
    tasks = {
        suite: {task: {k: row[k] for k in ("success_rate", "esr", "episodes")} for task, row in modes["base"].items()}
        for suite, modes in result["per_task"].items()
    }
    print(f"{'task':22s} {'success':>8s} {'ESR':>6s}")
    for suite, rows in tasks.items():
        for task, row in rows.items():
            print(f"{task:22s} {row['success_rate']:8.1%} {row['esr']:6.1%}")
        print(f"{suite + ' (suite)':22s} {suites[suite]['success_rate']:8.1%} {suites[suite]['esr']:6.1%}")
    print(
        json.dumps(
            {
                "benchmark": "policy_quality",
                "config": vars(args),
                "per_suite": suites,
                "per_task": tasks,
                "verdicts": verdicts(suites),
                "targets": TARGETS,
            }
        )
    )


if __name__ == "__main__":
    main()
