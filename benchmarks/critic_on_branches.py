"""How well does each critic rank the candidates whose outcomes the simulator already showed?

Takes a branch file written by `benchmarks/jiti_headroom.py --out` (every decision point's state,
candidates and the elegant-success outcome of executing each) and recomputes the summary with each
critic's Q (`elegant.rescore_headroom`): the critic's hit rate where the base episode was inelegant
against a random eligible candidate, its harm on elegant episodes, and `outcome_auroc` (0.5 = chance)
over the points whose eligible candidates' outcomes differ. No simulation: seconds per critic, so
critic variants are compared on the same ground truth instead of on noisy evaluation episodes.
One JSON object per critic.

    python benchmarks/critic_on_branches.py headroom.json CRITIC_DIR [CRITIC_DIR ...] [--trust-radius 0.3]
"""

from __future__ import annotations

import argparse
import json

from headroom import rescore_headroom

from base_suites.runtime.io import read_json_file


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("branches", help="a JSON written by benchmarks/jiti_headroom.py --out")
    parser.add_argument("critics", nargs="+")
    parser.add_argument("--trust-radius", type=float, default=0.3, help="<= 0 for none")
    args = parser.parse_args()
    radius = args.trust_radius if args.trust_radius > 0 else None
    result = read_json_file(args.branches, "headroom branches")
    for critic in args.critics:
        summary = rescore_headroom(result, critic, radius)["summary"]
        print(json.dumps({"benchmark": "critic_on_branches", "branches": args.branches, "critic": critic, **summary}))


if __name__ == "__main__":
    main()
