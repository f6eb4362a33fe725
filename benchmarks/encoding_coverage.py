"""Which tasks the goal-relative encoding reads (docs/design.md §4.4): every task of the chosen suites is built
on the real simulator, reset, and encoded; a task it refuses is listed with the reason.

    python benchmarks/encoding_coverage.py [--suites libero_spatial,libero_object,libero_goal,libero_10]
        [--with-pro] [--seed 0]

--with-pro adds each suite's LIBERO-PRO variants (`base_suites.suites.PRO_SUITES`). Prints one line per
suite, then one JSON object on its last line: per suite the tasks encoded and those refused, with why.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from tqdm import tqdm

from annotations import GoalFeatureEncoder
from base_suites import make_env
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.settings import str_list
from base_suites.suites import PRO_SUITES, base_suite_of, list_tasks

MAIN = ("libero_spatial", "libero_object", "libero_goal", "libero_10")


def coverage(suite: str, seed: int) -> dict:
    """Encode the first state of every task of `suite`; refusals keep their one-line reason."""
    encoder = GoalFeatureEncoder()
    encoded, refused = [], {}
    for task in tqdm(list_tasks(suite), desc=suite, unit="task", leave=False):
        try:
            env = make_env(suite, task.index, seed=seed)
        except UserInputError as e:  # a task LIBERO-PRO lists without its files
            refused[task.index] = f"not built: {e}"
            continue
        try:
            obs, _ = env.reset(seed=seed)
            features = encoder.encode(obs["state"], encoder.check_env(env.metadata))
            if not np.isfinite(features).all():
                raise UserInputError("features not finite")
            encoded.append(task.index)
        except UserInputError as e:
            refused[task.index] = str(e)
        finally:
            env.close()
    return {"encoded": encoded, "refused": refused}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("--suites", type=str_list, default=MAIN, help="base suites (default: the four main ones)")
    parser.add_argument("--with-pro", action="store_true", help="also each suite's LIBERO-PRO variants")
    parser.add_argument("--seed", type=int, default=0, help="the reset seed")
    args = parser.parse_args()
    suites = list(args.suites)
    if args.with_pro:
        suites += [s for s in PRO_SUITES if base_suite_of(s) in args.suites]
    result = {}
    for suite in suites:
        result[suite] = coverage(suite, args.seed)
        row = result[suite]
        print(f"{suite:28s} encoded {len(row['encoded']):3d}  refused {len(row['refused']):3d}", flush=True)
    totals = {k: sum(len(r[k]) for r in result.values()) for k in ("encoded", "refused")}
    print(json.dumps({"benchmark": "encoding_coverage", "seed": args.seed, "totals": totals, "per_suite": result}))


if __name__ == "__main__":
    main()
