"""How much can a one-step intervention do for this policy, and how much of it does the critic find?

Branches evaluation episodes in the simulator (`benchmarks/headroom.py`): at every EVERY-th step, each of N
candidates from the base policy is executed once and the base policy finishes the episode. Per episode
it prints one line per decision point, one character per candidate (candidate 0 = the base action):
E elegant success, . not, with the critic's choice marked by brackets; then the summary (headroom,
the critic's hit rate against a random eligible candidate, harm on elegant episodes) as one JSON object
on the last line; with --out, the branches also go to that JSON and a PNG beside it. Costly: about
N x (decision points) episodes per start.

    python benchmarks/jiti_headroom.py POLICY_DIR CRITIC_DIR --suite libero_object --task 0
        [--episodes 4 | --episodes 1,10,12] [--seed 3] [--every 15] [--first 10] [--candidates N]
        [--trust-radius R] [--min-gain G] [--out headroom.json]

The candidates' options are JITI's own (`JITIConfig`), with its defaults.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from headroom import intervention_headroom, plot_headroom

from base_suites.runtime.io import atomic_write_json
from base_suites.runtime.settings import add_settings_arguments, index_list, settings_from_args, with_overrides
from elegant.intervention.config import JITIConfig
from elegant.intervention.selectors import choose_candidate

# JITI's settings these branches use: how many candidates, and how the critic chooses among them
CHOICE_SETTINGS = ("n_candidates", "trust_radius", "min_gain")
OTHER_SETTINGS = tuple(name for name in JITIConfig.settings() if name not in CHOICE_SETTINGS)


def choice_settings(args) -> JITIConfig:
    """JITI's config with the choice settings given on the command line (`CHOICE_SETTINGS`)."""
    return with_overrides(JITIConfig(), settings_from_args(args, JITIConfig, OTHER_SETTINGS), "headroom")


def _row(point: dict, jiti: JITIConfig) -> str:
    q, distance = np.asarray(point["q"]), np.asarray(point["distance"])
    chosen = choose_candidate(q, distance, jiti.trust_radius, jiti.min_gain)
    marks = ["E" if e else "." for e in point["elegant"]]
    marks[chosen] = f"[{marks[chosen]}]"
    return f"  step {point['step']:4d}  " + "".join(marks)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policy")
    parser.add_argument("critic")
    parser.add_argument("--suite", default="libero_object")
    parser.add_argument("--task", type=int, default=0)
    parser.add_argument(
        "--episodes", default="4", help="a count N (episodes 0..N-1) or comma-separated episode indices"
    )
    parser.add_argument("--seed", type=int, default=3, help="the evaluation seed whose starts are branched")
    parser.add_argument("--every", type=int, default=15)
    parser.add_argument("--first", type=int, default=10)
    add_settings_arguments(parser, JITIConfig, OTHER_SETTINGS)
    parser.add_argument("--max-steps", type=int)
    parser.add_argument(
        "--init-states",
        type=index_list,
        help="as elegant eval --init-states: the subset the starts are drawn from, e.g. 25-49",
    )
    parser.add_argument("--out", help="write every branch outcome here (JSON)")
    args = parser.parse_args()
    jiti = choice_settings(args)
    episodes = [int(e) for e in args.episodes.split(",")] if "," in args.episodes else list(range(int(args.episodes)))
    result = intervention_headroom(
        args.suite,
        args.task,
        args.policy,
        args.critic,
        episodes=episodes,
        seed=args.seed,
        every=args.every,
        first=args.first,
        jiti=jiti,
        max_steps=args.max_steps,
        init_states=args.init_states,
    )
    for episode in result["episodes"]:
        print(
            f"init {episode['init_index']}: base {'elegant success' if episode['base_elegant'] else 'not elegant'}, "
            f"{episode['steps']} steps"
        )
        for point in episode["points"]:
            print(_row(point, jiti))
    if args.out:
        atomic_write_json(args.out, result)
        plot_headroom(result, jiti, Path(args.out).with_suffix(".png"))
    print(json.dumps({"benchmark": "jiti_headroom", "policy": args.policy, "critic": args.critic, **result["summary"]}))


if __name__ == "__main__":
    main()
