"""Does a critic rank a policy's alternatives by where they lead? Measured on annotated branch rollouts.

JITI helps only where, at a decision, the critic scores an alternative above the policy's own plan when
the alternative leads to a better episode. `elegant rollouts --explore-at` records exactly that evidence:
each episode follows the policy except for one random candidate (within the trust radius) at one
decision, and `elegant annotate` says whether it ended elegant. For every such episode this replays the
recorded observations through the policy up to the explored decision (so a policy with a history window
sees what it saw; its actions there must be the recorded ones, which also proves the file is this
policy's), takes the plan it would have executed (JITI's candidate 0), and scores the plan and the
explored chunk with the critic at the recorded state. Per task and pooled:

- `advantage_auroc`: how well Q(explored) - Q(plan) separates the episodes that ended elegant from those
  that did not (0.5: chance, 1: perfect); this is the critic's job in JITI;
- `q_auroc`: the same for Q(explored) alone, which mostly measures how well the critic reads the state;
- `prefers_explored`: how often Q(explored) > Q(plan), against `elegant_rate`.

On the critic's own training rollouts these figures show memorisation (`q_auroc` near 1); on rollouts from
starts it never saw (the evaluation's), they show what JITI can rely on, in seconds and without the
simulator, where an `elegant eval` comparison costs minutes and is noisier.
"""

from __future__ import annotations

from collections import defaultdict
from typing import Any

import numpy as np
from tqdm import tqdm

from annotations import Demo, DemoFile
from base_suites.runtime.errors import UserInputError
from critics import auroc, explored_mask
from elegant.intervention.jiti import check_critic_chunk, decide
from elegant.policies.protocol import chunk_of

# Recorded actions are stored as float32; the policy's own are float64.
_SAME_ACTION_ATOL = 1e-5


def _metadata(f: DemoFile, demo: Demo) -> dict[str, Any]:
    """What a policy's `reset` and a critic's `bind` read from env.metadata, from the file instead."""
    attrs = demo.attrs
    return {
        "suite": attrs["suite"],
        "task_index": int(attrs["task_index"]),
        "instruction": attrs.get("language_instruction", ""),
        "state_layout": f.state_layouts[demo.task_key],
        "goal_geometry": attrs.get("goal_geometry"),
    }


def single_explored_step(demo: Demo, chunk: int, where: str) -> int | None:
    """The step of an episode's one explored decision, or None when it explored none or several, or ended
    inside the explored chunk: only such episodes compare one alternative with the plan."""
    steps = np.flatnonzero(explored_mask(demo.attrs, len(demo.actions), where))
    if len(steps) != 1 or steps[0] + chunk > len(demo.actions):
        return None
    return int(steps[0])


def _summary(rows: list[tuple[bool, float, float]], skipped: int) -> dict[str, Any]:
    elegant = np.array([r[0] for r in rows], dtype=bool)
    advantage = np.array([r[1] - r[2] for r in rows])
    q_explored = np.array([r[1] for r in rows])
    return {
        "episodes": len(rows),
        "skipped": skipped,
        "elegant_rate": float(elegant.mean()) if rows else None,
        "advantage_auroc": auroc(advantage[elegant], advantage[~elegant]),
        "q_auroc": auroc(q_explored[elegant], q_explored[~elegant]),
        "prefers_explored": float((advantage > 0).mean()) if rows else None,
    }


def branch_ranking(path: str, policy: Any, critic: Any, *, progress: bool = False) -> dict[str, Any]:
    """Rank every singly-explored episode of the annotated rollouts file `path` (see module doc).

    `policy` is an adapted policy (`elegant.policies.as_policy`), `critic` a loaded critic. Episodes with
    no explored decision, with several, or that end inside the explored chunk are counted as skipped."""
    chunk = chunk_of(policy)
    check_critic_chunk(critic, chunk)
    rows: dict[str, list[tuple[bool, float, float]]] = defaultdict(list)
    skipped: dict[str, int] = defaultdict(int)
    with DemoFile(path, require_labels=True) as f:
        for name in tqdm(f.names, desc="rank", unit="ep", disable=not progress):
            demo = f.demo(name)
            where = f"{path}: data/{name}"
            key = demo.task_key
            explored_at = single_explored_step(demo, chunk, where)
            if explored_at is None:
                skipped[key] += 1
                continue
            metadata = _metadata(f, demo)  # per episode: a goal-relative critic reads the episode's goal geometry
            policy.reset(metadata, seed=0)
            critic.bind(metadata)
            for t in range(explored_at):
                action = np.asarray(policy({"state": demo.obs[t]}), dtype=np.float64)
                if not np.allclose(np.clip(action, -1.0, 1.0), demo.actions[t], atol=_SAME_ACTION_ATOL):
                    raise UserInputError(
                        f"{where}: step {t}: the policy acts otherwise than recorded; rank with the policy that "
                        "recorded "
                        f"the rollouts (attr policy: {demo.attrs.get('policy', 'not recorded')})"
                    )
            state = demo.obs[explored_at]
            plan = decide(policy, {"state": state}, chunk)
            explored = demo.actions[explored_at : explored_at + chunk]
            q_plan, q_explored = critic.q(state, np.stack([plan.reshape(-1), explored.reshape(-1)]))
            rows[key].append((bool(demo.attrs["elegant"]), float(q_explored), float(q_plan)))
    tasks = sorted(set(rows) | set(skipped))
    return {
        "file": path,
        "tasks": {k: _summary(rows[k], skipped[k]) for k in tasks},
        "all": _summary([r for k in tasks for r in rows[k]], sum(skipped.values())),
    }
