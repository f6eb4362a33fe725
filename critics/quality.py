"""Held-out quality of a critic: does Q rank the dataset's elegant actions above its inelegant ones?

Each step of each held-out demo is labelled by the 25-frame segment it falls in: *elegant* when the
segment kept all four criteria, *violated* otherwise. The headline figure is the AUROC of Q(s_t, a_t)
separating elegant from violated steps (0.5: no better than chance; 1: every elegant action scores above
every violated one). Per criterion, the same AUROC separates segments that kept that criterion from
segments that violated it.
"""

from __future__ import annotations

import os
from collections.abc import Collection, Sequence
from typing import Any

import numpy as np

from annotations import CRITERIA, DemoFile
from base_suites.runtime.errors import UserInputError
from critics.artifact import Critic, load
from critics.data import action_chunks, segment_length, step_window_labels


def auroc(positive: np.ndarray, negative: np.ndarray) -> float | None:
    """P(score of a random positive > score of a random negative), ties counting half; None if a side is empty."""
    positive, negative = np.asarray(positive, dtype=np.float64).ravel(), np.asarray(negative, dtype=np.float64).ravel()
    if len(positive) == 0 or len(negative) == 0:
        return None
    scores = np.concatenate([positive, negative])
    order = np.argsort(scores, kind="mergesort")
    _, first, counts = np.unique(scores[order], return_index=True, return_counts=True)
    ranks = np.empty(len(scores))
    ranks[order] = np.repeat(first + (counts + 1) / 2, counts)  # 1-based average rank of each tie group
    u = ranks[: len(positive)].sum() - len(positive) * (len(positive) + 1) / 2
    return float(u / (len(positive) * len(negative)))


def _score_file(
    critic: Critic, path: str, tasks: Collection[str] | None = None
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Q of every dataset action in the file (of `tasks`' demos only, if given), and per criterion whether
    its step's segment kept it. Each demo binds anew: a goal-relative critic reads its goal geometry."""
    q, kept = [np.zeros(0, dtype=np.float32)], {c: [np.zeros(0, dtype=bool)] for c in CRITERIA}
    with DemoFile(path, require_labels=True) as f:
        length = segment_length(f)
        layouts = f.state_layouts
        for demo in f:
            key = demo.task_key
            if tasks is not None and key not in tasks:
                continue
            if key not in layouts:
                raise UserInputError(f"{path}: data.state_layouts has no layout for task {key}")
            meta = {
                "suite": demo.attrs["suite"],
                "task_index": demo.attrs["task_index"],
                "state_layout": layouts[key],
                "goal_geometry": demo.attrs.get("goal_geometry"),
            }
            binding = critic._binding_for(meta)
            q.append(critic._score(binding, demo.obs, action_chunks(demo.actions, critic.chunk)[:, None, :])[:, 0])
            for c, labels in step_window_labels(demo, length, f"{path}: data/{demo.name}").items():
                kept[c].append(labels)
    return np.concatenate(q), {c: np.concatenate(v) for c, v in kept.items()}


def evaluate_critic(
    critic_or_dir: Critic | str | os.PathLike, annotated_paths: Sequence[str], tasks: Collection[str] | None = None
) -> dict[str, Any]:
    """Held-out AUROC of a critic on annotated files (on `tasks`' demos only, if given: keys "suite/index").

    Returns: auroc (elegant vs violated steps; None if either is absent), n_elegant, n_violated,
    mean_q_elegant, mean_q_violated, per_criterion ({criterion: {auroc, n_kept, n_violated}}), transitions,
    files.
    """
    critic = critic_or_dir if isinstance(critic_or_dir, Critic) else load(critic_or_dir)
    if not annotated_paths:
        raise UserInputError("evaluate_critic: no annotated HDF5 files given")
    scored = [_score_file(critic, str(p), tasks) for p in annotated_paths]
    q = np.concatenate([s[0] for s in scored])
    kept = {c: np.concatenate([s[1][c] for s in scored]) for c in CRITERIA}
    elegant = np.logical_and.reduce([kept[c] for c in CRITERIA])

    def mean(x: np.ndarray) -> float | None:
        return float(x.mean()) if len(x) else None

    return {
        "auroc": auroc(q[elegant], q[~elegant]),
        "n_elegant": int(elegant.sum()),
        "n_violated": int((~elegant).sum()),
        "mean_q_elegant": mean(q[elegant]),
        "mean_q_violated": mean(q[~elegant]),
        "per_criterion": {
            c: {
                "auroc": auroc(q[kept[c]], q[~kept[c]]),
                "n_kept": int(kept[c].sum()),
                "n_violated": int((~kept[c]).sum()),
            }
            for c in CRITERIA
        },
        "transitions": int(len(q)),
        "files": [str(p) for p in annotated_paths],
    }
