"""Do sibling contrasts teach a ranker what a chunk adds? A pairwise loss on branch rollouts, judged by rank-check.

`elegant rollouts --explore-at` branches every start at several decisions, and the branches of one start
share its reset seed, so a branch exploring at step t and a sibling exploring later were in the same state
at t and differ in the chunk executed there: the explored one against the policy's plan. A Cal-QL critic
fits each row's outcome on its own and can explain it by the state; this fits, per task, a small network
f(state, chunk) -> logit on the explored rows (cross-entropy on elegance) and, with weight `--pair-weight`,
on those sibling pairs whose outcomes differ (a logistic loss on f(s, explored) - f(s, plan)), then
reports `elegant rank-check`'s held-out advantage AUROC for each weight and seed.

    python benchmarks/pairwise_ranker.py --train A.annotated.hdf5,B.annotated.hdf5 --test C.annotated.hdf5 \
        --policy policy/ [--pair-weights 0,1] [--seeds 0,1] [--steps 3000]
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from annotations import DemoFile
from elegant.diagnostics.branch_ranking import branch_ranking, single_explored_step
from elegant.evaluation.runner import open_policy
from elegant.policies.adapters import as_policy
from elegant.policies.protocol import chunk_of


@dataclass
class Branch:
    task: int
    start: tuple[int, int]  # (init state, reset seed)
    explored_at: int | None
    elegant: float
    obs: np.ndarray
    actions: np.ndarray


def read_branches(path: str, chunk: int) -> list[Branch]:
    """Every episode of an annotated rollouts file (`explored_at` as rank-check counts it)."""
    branches = []
    with DemoFile(path, require_labels=True) as f:
        for demo in f:
            branches.append(
                Branch(
                    int(demo.attrs["task_index"]),
                    (int(demo.attrs["init_state_index"]), int(demo.attrs["reset_seed"])),
                    single_explored_step(demo, chunk, path),
                    float(demo.attrs["elegant"]),
                    np.asarray(demo.obs),
                    np.asarray(demo.actions),
                )
            )
    return branches


def rows_and_pairs(
    branches: list[Branch], chunk: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(explored inputs, their elegance, pair inputs explored / plan, pair targets) of one task's branches.
    A pair is an explored branch and a sibling that executed the plan over the whole explored chunk, from
    the identical recorded state, with another outcome."""
    siblings = defaultdict(list)
    for b in branches:
        siblings[b.start].append(b)
    inputs, elegant, pair_explored, pair_plan, pair_target = [], [], [], [], []
    for b in branches:
        t = b.explored_at
        if t is None:
            continue
        state, explored = b.obs[t], b.actions[t : t + chunk].reshape(-1)
        inputs.append(np.concatenate([state, explored]))
        elegant.append(b.elegant)
        for sib in siblings[b.start]:
            planned_through = sib.explored_at if sib.explored_at is not None else len(sib.actions)
            if (
                sib is b
                or planned_through < t + chunk
                or sib.elegant == b.elegant
                or not np.array_equal(sib.obs[t], state)
            ):
                continue
            pair_explored.append(inputs[-1])
            pair_plan.append(np.concatenate([state, sib.actions[t : t + chunk].reshape(-1)]))
            pair_target.append(float(b.elegant > sib.elegant))
    width = len(inputs[0])
    as_array = lambda rows: np.array(rows, dtype=np.float32).reshape(-1, width)  # noqa: E731
    return (
        as_array(inputs),
        np.array(elegant, dtype=np.float32),
        as_array(pair_explored),
        as_array(pair_plan),
        np.array(pair_target, dtype=np.float32),
    )


class Ranker:
    """Per-task networks behind the critic interface `branch_ranking` uses (`chunk`, `bind`, `q`)."""

    def __init__(self, models: dict[int, tuple[torch.nn.Module, np.ndarray, np.ndarray]], chunk: int) -> None:
        self.models, self.chunk, self._bound = models, chunk, None

    def bind(self, metadata: dict[str, Any]) -> Ranker:
        self._bound = self.models[int(metadata["task_index"])]
        return self

    def q(self, state: np.ndarray, actions: np.ndarray) -> np.ndarray:
        net, mean, std = self._bound
        x = np.concatenate([np.repeat(state[None], len(actions), 0), actions], 1)
        with torch.no_grad():
            return net(torch.as_tensor((x - mean) / std, dtype=torch.float32)).squeeze(-1).numpy()


def fit(
    data: tuple[np.ndarray, ...], pair_weight: float, seed: int, steps: int
) -> tuple[torch.nn.Module, np.ndarray, np.ndarray]:
    """A 64x64 network (AdamW, weight decay 0.1, batches of 256) on one task's rows and, weighted, its pairs."""
    inputs, elegant, pair_explored, pair_plan, pair_target = data
    torch.manual_seed(seed)
    mean, std = inputs.mean(0), inputs.std(0) + 1e-3
    scaled = lambda x: torch.as_tensor((x - mean) / std, dtype=torch.float32)  # noqa: E731
    net = torch.nn.Sequential(
        torch.nn.Linear(inputs.shape[1], 64),
        torch.nn.ReLU(),
        torch.nn.Linear(64, 64),
        torch.nn.ReLU(),
        torch.nn.Linear(64, 1),
    )
    opt = torch.optim.AdamW(net.parameters(), lr=1e-3, weight_decay=0.1)
    x, y = scaled(inputs), torch.as_tensor(elegant)
    px, pp, py = scaled(pair_explored), scaled(pair_plan), torch.as_tensor(pair_target)
    logistic = torch.nn.functional.binary_cross_entropy_with_logits
    for _ in range(steps):
        i = torch.randint(len(x), (256,))
        loss = logistic(net(x[i]).squeeze(-1), y[i])
        if pair_weight > 0 and len(py):
            j = torch.randint(len(py), (256,))
            loss = loss + pair_weight * logistic((net(px[j]) - net(pp[j])).squeeze(-1), py[j])
        opt.zero_grad()
        loss.backward()
        opt.step()
    return net.eval(), mean, std


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train", required=True, help="comma-separated annotated branch rollouts to fit on")
    parser.add_argument("--test", required=True, help="comma-separated annotated branch rollouts from other starts")
    parser.add_argument("--policy", required=True, help="the policy that recorded them")
    parser.add_argument("--pair-weights", default="0,1")
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--steps", type=int, default=3000)
    args = parser.parse_args()
    torch.set_num_threads(1)
    policy = as_policy(open_policy(args.policy), seed=0)
    chunk = chunk_of(policy)
    branches = [b for path in args.train.split(",") for b in read_branches(path, chunk)]
    per_task = {
        task: rows_and_pairs([b for b in branches if b.task == task], chunk)
        for task in sorted({b.task for b in branches})
    }
    for task, data in per_task.items():
        print(json.dumps({"task": task, "explored_rows": len(data[0]), "pairs": len(data[4])}), flush=True)
    means = {}
    for weight in (float(w) for w in args.pair_weights.split(",")):
        runs = []
        for seed in (int(s) for s in args.seeds.split(",")):
            ranker = Ranker({task: fit(data, weight, seed, args.steps) for task, data in per_task.items()}, chunk)
            runs.append(
                {path: branch_ranking(path, policy, ranker)["all"]["advantage_auroc"] for path in args.test.split(",")}
            )
            print(
                json.dumps(
                    {
                        "pair_weight": weight,
                        "seed": seed,
                        "advantage_auroc": {k: round(v, 3) for k, v in runs[-1].items()},
                    }
                ),
                flush=True,
            )
        means[str(weight)] = {path: round(float(np.mean([r[path] for r in runs])), 3) for path in runs[0]}
    print(json.dumps({"mean_advantage_auroc_by_pair_weight": means}))


if __name__ == "__main__":
    main()
