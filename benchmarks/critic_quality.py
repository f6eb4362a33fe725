"""Held-out quality of the elegance critic: train on one annotated file, rank the actions of another.

Trains a Cal-QL critic on TRAIN (annotated HDF5, e.g. scripted-expert demos labelled by `elegant
annotate`), then reports `critics.evaluate_critic` on HELDOUT: the AUROC of Q separating dataset actions
in elegant 25-frame segments from those in segments that violate a criterion, overall and per criterion.
Last line: one JSON object {"train": training summary, "heldout": evaluation}.

    python benchmarks/critic_quality.py TRAIN.hdf5 HELDOUT.hdf5 [--steps 20000] [--out DIR]
"""
from __future__ import annotations

import argparse
import json
import tempfile

import torch

from critics import BACKUPS, REWARDS, evaluate_critic, train_critic


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("train", help="annotated HDF5 to train on")
    parser.add_argument("heldout", help="annotated HDF5 to evaluate on")
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--batch-size", type=int, default=256)
    parser.add_argument("--hidden", type=int, nargs="+", default=[256, 256])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--gamma", type=float, help="the critic's discount (default: the annotation's)")
    parser.add_argument("--cql-weight", type=float, default=5.0)
    parser.add_argument("--reward", choices=REWARDS, default="step", help="violation penalty per step or per 25-frame window")
    parser.add_argument("--backup", choices=BACKUPS, default="policy", help="the TD target's next action (see CalQLLoss)")
    parser.add_argument("--threads", type=int, default=torch.get_num_threads())
    parser.add_argument("--out", help="critic directory to keep (default: a temporary one)")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    with tempfile.TemporaryDirectory(prefix="critic_quality_") as tmp:
        out = args.out or tmp
        summary = train_critic([args.train], out, steps=args.steps, batch_size=args.batch_size, hidden=args.hidden,
                               seed=args.seed, gamma=args.gamma, cql_weight=args.cql_weight, reward=args.reward,
                               backup=args.backup, progress=not args.no_progress)
        report = evaluate_critic(out, [args.heldout])
    print(json.dumps({"train": summary, "heldout": report}))


if __name__ == "__main__":
    main()
