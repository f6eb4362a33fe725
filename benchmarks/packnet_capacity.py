"""Why PackNet learns little on the BC network: capacity or interference, read off the demos' likelihood.

Two measurements on finished `elegant lifelong` runs (one seed directory each, e.g. OUT/packnet/seed_0):

1. Per stage: the mean log-likelihood of task k's demos under the network at the end of stage k, for every
   run given (PackNet's stage k trains only the weights earlier tasks left free:
   packnet_prune^k of them).
2. Probes on one task, trained from the PackNet run's fresh network for the run's epochs with only a
   random fraction f of the Linear weights trainable (`WeightMasks`, as PackNet trains):
   "sparse" zeroes the other weights and starts the free ones at their initial values (capacity alone);
   "packlike" keeps the other weights at their random initial values and starts the free ones at zero
   (PackNet's start, with untrained rather than trained fixed weights).

    python benchmarks/packnet_capacity.py runs/lifelong10_obj/packnet/seed_0 runs/lifelong10_obj/seql/seed_0 \
        --out runs/packnet_capacity [--task 5] [--fractions 1,0.75,0.42,0.24,0.1] [--seed 0]

Trained probes go to OUT (each beside its start network and, for f < 1, the masks of the weights held fixed,
owner 1) and are reused when rerun. Prints a table, then one JSON object on its last line.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import read_json_file
from elegant.evaluation.lifelong_algos.packnet import PACKNET_MASKS_FILE
from elegant.evaluation.lifelong_run import stage_policy_config
from elegant.policies.bc_artifact import read_artifact, write_artifact
from elegant.policies.bc_data import DemoSet, load_demos
from elegant.policies.bc_train import FineTuning, demo_batches, select_tasks, snapshot_dir, train_policy
from elegant.policies.continual import WeightMasks, linear_weights

VARIANTS = ("sparse", "packlike")


def demo_log_likelihood(policy_dir: str, data: DemoSet) -> float:
    """Mean log-likelihood of every sample of `data` under the policy in `policy_dir`."""
    net, features, _ = read_artifact(policy_dir)
    total, count = 0.0, 0
    with torch.no_grad():
        for x, actions in demo_batches(data, features, chunk=1, batch_size=1024, seed=0):
            total += float(-net.nll(x, actions).sum())
            count += len(x)
    return total / count


def stage_fits(run: Path, config: dict[str, Any], data: DemoSet) -> list[float]:
    """Task k's demo log-likelihood at the end of stage k (its last snapshot), for every stage of `run`
    (whose recorded `config` is given)."""
    last = config["eval_epochs"][-1]
    return [
        demo_log_likelihood(snapshot_dir(str(run / "stages" / f"task_{k}"), last), select_tasks(data, [key]))
        for k, key in enumerate(config["task_keys"])
    ]


def train_probe(
    run: Path, config: dict[str, Any], out: Path, task: str, fraction: float, variant: str, seed: int
) -> str:
    """Train `task` from `run`'s fresh network (`config`: its recorded settings) with a random `fraction`
    of the Linear weights trainable."""
    probe = out / f"{variant}_{fraction}"
    if (probe / "config.json").exists():
        return str(probe)
    net, features, artifact = read_artifact(snapshot_dir(str(run / "stages" / "task_0"), 0))
    generator = torch.Generator().manual_seed(seed)
    owner = {}
    with torch.no_grad():
        for name, weight in linear_weights(net).items():
            free = torch.rand(weight.shape, generator=generator) < fraction
            weight[~free if variant == "sparse" else free] = 0.0
            owner[name] = torch.where(free, 0, 1).to(torch.int16)  # 1: owned by an earlier "task 0"
    start = out / f"{variant}_{fraction}_start"
    start.mkdir(parents=True, exist_ok=True)
    write_artifact(str(start), net, features, artifact["model"], artifact["training"])
    masks = None
    if fraction < 1.0:
        WeightMasks(owner, 0).save(str(start / PACKNET_MASKS_FILE))  # which weights were held fixed
        masks = WeightMasks(owner, 1, claim_free=True)
    train_policy(
        [d["path"] for d in config["data"]],
        str(probe),
        stage_policy_config(config),
        successful_only=False,
        progress=False,
        fine_tuning=FineTuning(tasks=[task], init_from=str(start), masks=masks),
    )
    return str(probe)


def parse_fractions(text: str) -> list[float]:
    try:
        fractions = [float(f) for f in text.split(",")]
    except ValueError:
        raise UserInputError(f"--fractions: expected comma-separated numbers in (0, 1], got {text!r}") from None
    if not fractions or any(not 0.0 < f <= 1.0 for f in fractions):
        raise UserInputError(f"--fractions: expected comma-separated numbers in (0, 1], got {text!r}")
    return fractions


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("packnet_run", type=Path, help="a finished PackNet seed directory (OUT/packnet/seed_N)")
    parser.add_argument("other_runs", type=Path, nargs="*", help="more finished seed directories to compare")
    parser.add_argument("--out", type=Path, required=True, help="where the probes are trained (reused when rerun)")
    parser.add_argument("--task", type=int, default=5, help="the position in the learning order the probes train")
    parser.add_argument("--fractions", default="1,0.75,0.42,0.24,0.1", help="free fractions of the probes")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random choice of free weights")
    args = parser.parse_args()
    try:
        fractions = parse_fractions(args.fractions)
        runs = [args.packnet_run, *args.other_runs]
        configs = [read_json_file(run / "config.json", "lifelong run config") for run in runs]
        if configs[0].get("algorithm") != "packnet":
            raise UserInputError(f"{runs[0]}/config.json: algorithm is {configs[0].get('algorithm')!r}, not packnet")
        keys = configs[0]["task_keys"]
        if not 0 <= args.task < len(keys):
            raise UserInputError(f"--task: expected a position from 0 to {len(keys) - 1}, got {args.task}")
        data = load_demos([d["path"] for d in configs[0]["data"]])
    except UserInputError as exc:
        sys.exit(f"packnet_capacity: {exc}")
    prune = configs[0]["algorithm_settings"]["packnet_prune"]
    fits = {f"{c['algorithm']}:{run}": stage_fits(run, c, data) for run, c in zip(runs, configs)}
    task_data = select_tasks(data, [keys[args.task]])
    probes: dict[str, dict[str, float]] = {variant: {} for variant in VARIANTS}
    for fraction in fractions:
        for variant in VARIANTS[:1] if fraction == 1.0 else VARIANTS:
            probe = train_probe(args.packnet_run, configs[0], args.out, keys[args.task], fraction, variant, args.seed)
            probes[variant][str(fraction)] = demo_log_likelihood(probe, task_data)
    print("stage fits (task k's demos at the end of stage k):")
    for name, values in fits.items():
        print(f"  {name}: " + ", ".join(f"{v:.1f}" for v in values))
    print(f"probes on {keys[args.task]}: free fraction, sparse, packlike")
    for fraction in fractions:
        row = [probes[v].get(str(fraction)) for v in VARIANTS]
        print(f"  {fraction:5.2f} " + " ".join("    —" if v is None else f"{v:5.1f}" for v in row))
    print(
        json.dumps(
            {
                "benchmark": "packnet_capacity",
                "config": vars(args),
                "stage_log_likelihood": fits,
                "probe_task": keys[args.task],
                "probe_log_likelihood": probes,
                "free_fraction_of_stage": [prune**k for k in range(len(keys))],
                "stage_mean": {name: float(np.mean(v)) for name, v in fits.items()},
            },
            default=str,
        )
    )


if __name__ == "__main__":
    main()
