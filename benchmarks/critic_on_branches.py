"""How well does each critic rank the candidates whose outcomes the simulator already showed?

Takes a branch file written by `benchmarks/jiti_headroom.py --out` (every decision point's state,
candidates and the elegant-success outcome of executing each) and recomputes the summary with each
critic's Q (`elegant.rescore_headroom`): the critic's hit rate where the base episode was inelegant
against a random eligible candidate, its harm on elegant episodes, and `outcome_auroc` (0.5 = chance)
over the points whose eligible candidates' outcomes differ. No simulation: seconds per critic, so
critic variants are compared on the same ground truth instead of on noisy evaluation episodes.
One JSON object per critic.

    python benchmarks/critic_on_branches.py headroom.json CRITIC_DIR [CRITIC_DIR ...] [--trust-radius R]

The choice's options are JITI's own (`JITIConfig`), with its defaults.
"""

from __future__ import annotations

import argparse
import json

from headroom import rescore_headroom
from jiti_headroom import CHOICE_SETTINGS, choice_settings

from base_suites.runtime.io import read_json_file
from base_suites.runtime.settings import add_settings_arguments
from elegant.intervention.config import JITIConfig


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("branches", help="a JSON written by benchmarks/jiti_headroom.py --out")
    parser.add_argument("critics", nargs="+")
    # the candidates are the branch file's: only how the critic chooses among them is an option
    add_settings_arguments(parser, JITIConfig, tuple(n for n in JITIConfig.settings() if n not in CHOICE_SETTINGS[1:]))
    args = parser.parse_args()
    jiti = choice_settings(args)
    result = read_json_file(args.branches, "headroom branches")
    for critic in args.critics:
        summary = rescore_headroom(result, critic, jiti)["summary"]
        print(json.dumps({"benchmark": "critic_on_branches", "branches": args.branches, "critic": critic, **summary}))


if __name__ == "__main__":
    main()
