"""Held-out quality of the elegance critic: train on annotated files, rank the actions of others.

Trains a Cal-QL critic on the TRAIN files (annotated HDF5, e.g. scripted-expert demos labelled by
`elegant annotate`), then reports `critics.evaluate_critic` on the HELDOUT files: the AUROC of Q separating
dataset actions in elegant 25-frame segments from those in segments that violate a criterion, overall and
per criterion.
With --reference it also fits a network of the critic's size by plain regression on the training
demos' discounted returns (Monte Carlo, the same gamma and reward) and evaluates it the same way: what
the data supports for ranking held-out actions, without any offline-RL machinery. A critic near that
reference is limited by its data, not by Cal-QL.
Last line: one JSON object {"train": training summary, "heldout": evaluation[, "reference": evaluation]}.

    python benchmarks/critic_quality.py TRAIN.hdf5 [TRAIN2.hdf5 ...] --heldout HELDOUT.hdf5 [...] [--steps 20000]
        [--out DIR] [every `elegant train-critic` option]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from dataclasses import replace

import torch
from torchrl.objectives.value.functional import reward2go

from base_suites.runtime.settings import add_settings_arguments, settings_from_args, with_overrides
from critics import (
    Critic,
    TrainConfig,
    TwinQNetwork,
    evaluate_critic,
    load_transitions,
    make_replay_buffer,
    train_critic,
)


def mc_regression_reference(paths: list[str], config: TrainConfig) -> Critic:
    """A one-critic `TwinQNetwork` regressed onto the discounted return of each (state, action) of the
    demos (the critic's data, one action per transition), wrapped as a run-time `Critic`. Demos cut off
    without success keep their return as it is (the Cal-QL floor leaves those out; a regression needs a
    target for every transition)."""
    steps, batch_size, hidden, seed = config.steps, config.batch_size, config.hidden, config.seed
    torch.manual_seed(seed)
    data = load_transitions(paths, replace(config, chunk=1))
    td = data.transitions
    td["mc_target"] = reward2go(td["next", "reward"], td["next", "done"], data.gamma, time_dim=-2)
    network = TwinQNetwork(data.obs_dim, data.action_dim, hidden, n_critics=1)
    optimizer = torch.optim.Adam(network.parameters(), lr=3e-4)
    buffer = make_replay_buffer(td, batch_size, torch.Generator().manual_seed(seed))
    for _ in range(steps):
        batch = buffer.sample()
        q = network(batch["observation"], batch["action"][:, None, :])[0, :, 0]
        loss = (q - batch["mc_target"][:, 0]).pow(2).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    return Critic(network, data.encoder, data.normalization, {"gamma": data.gamma}, path="mc-regression reference")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("train", nargs="+", help="annotated HDF5 files to train on")
    parser.add_argument("--heldout", nargs="+", required=True, help="annotated HDF5 files to evaluate on")
    add_settings_arguments(parser, TrainConfig, exclude=("paths",))
    parser.add_argument("--threads", type=int, default=torch.get_num_threads())
    parser.add_argument("--out", help="critic directory to keep (default: a temporary one)")
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument(
        "--reference", action="store_true", help="also evaluate a plain regression on Monte-Carlo returns"
    )
    args = parser.parse_args()
    config = with_overrides(TrainConfig(), settings_from_args(args, TrainConfig, exclude=("paths",)), "critic_quality")
    torch.set_num_threads(args.threads)

    with tempfile.TemporaryDirectory(prefix="critic_quality_") as tmp:
        out = args.out or tmp
        summary = train_critic(args.train, out, config, progress=not args.no_progress)
        result = {"train": summary, "heldout": evaluate_critic(out, args.heldout)}
    if args.reference:
        reference = mc_regression_reference(args.train, config)
        result["reference"] = evaluate_critic(reference, args.heldout)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
