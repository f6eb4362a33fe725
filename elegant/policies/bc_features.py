"""Model inputs of the BC policy: normalised, encoded states over a short history, plus the binary part.

Training and the running policy build inputs with the same two steps, so they cannot drift apart:
`encode` for each state, and `flatten_window` for the last `history` encoded states. The window repeats
the first state of an episode until enough steps exist, so the first action sees a full-width input like
every other. Two encodings (docs/design.md §4.4):
- task-onehot: per-task normalisation of the raw state (the same padded slot holds different objects in
  different tasks), then padding and the task one-hot;
- goal-relative: the goal-relative features, their continuous part normalised over all tasks' demos (a
  slot means the same thing in every task); the binary part (the goal's structure) is what FiLM reads.
Dimensions that barely vary in the demos get a floor on their scale so small run-time deviations do not
explode.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from annotations import FeatureEncoder, GoalContext, GoalFeatureEncoder, encoder_from_dict, make_encoder
from elegant.policies.bc_data import DemoSet, Episode

ALL_TASKS = "*"  # the goal-relative encoding's one set of normalisation statistics


class BCFeatures:
    """The encoder, normalisation and history length that define a BC model's input."""

    def __init__(self, encoder: FeatureEncoder, stats: Mapping[str, Mapping[str, Any]], history: int) -> None:
        self.encoder = encoder
        self.history = int(history)
        self.stats = {
            k: (np.asarray(v["mean"], dtype=np.float64), np.asarray(v["std"], dtype=np.float64))
            for k, v in stats.items()
        }

    @classmethod
    def fit(cls, data: DemoSet, *, history: int, min_std: float, encoding: str = "task-onehot") -> BCFeatures:
        encoder = make_encoder(encoding, data.layouts)
        groups: dict[str, list[np.ndarray]] = {}
        for episode in data.episodes:
            if isinstance(encoder, GoalFeatureEncoder):
                context = encoder.check_env(episode.metadata, episode.source)
                groups.setdefault(ALL_TASKS, []).append(encoder.encode(episode.states, context)[:, : encoder.state_dim])
            else:
                groups.setdefault(episode.task, []).append(episode.states)
        stats = {}
        for key, parts in groups.items():
            values = np.concatenate(parts).astype(np.float64)
            stats[key] = {"mean": values.mean(0), "std": np.maximum(values.std(0), min_std)}
        return cls(encoder, stats, history)

    @property
    def state_dim(self) -> int:
        return self.encoder.state_dim

    @property
    def binary_dim(self) -> int:
        """Width of the encoding's binary part: the task one-hot, or the goal's structure."""
        return self.encoder.dim - self.encoder.state_dim

    @property
    def input_dim(self) -> int:
        return self.history * self.encoder.state_dim + self.binary_dim

    def context(self, metadata: Mapping[str, Any], where: str) -> str | GoalContext:
        """What `encode` needs of an env or a demo (`metadata`: suite, task_index, state_layout, goal_geometry),
        refusing one the encoding cannot read."""
        return self.encoder.check_env(metadata, where)

    def context_of(self, episode: Episode) -> str | GoalContext:
        """An episode's context: its task key (whose layout `load_demos` checked), or its goal plan."""
        if isinstance(self.encoder, GoalFeatureEncoder):
            return self.context(episode.metadata, episode.source)
        return episode.task

    def width(self, context: str | GoalContext) -> int:
        """The raw state width of the task `context` plans for."""
        return context.state_size if isinstance(context, GoalContext) else self.stats[context][0].shape[0]

    def noise_width(self, episode: Episode) -> int:
        """The leading encoded entries the task fills (the padding of a task one-hot is not observed)."""
        return self.state_dim if isinstance(self.encoder, GoalFeatureEncoder) else self.width(episode.task)

    def encode(self, states: np.ndarray, context: str | GoalContext) -> np.ndarray:
        """(..., D_task) raw states of the task `context` plans for -> (..., encoder.dim) float32 features."""
        if isinstance(context, GoalContext):
            features = self.encoder.encode(states, context)
            mean, std = self.stats[ALL_TASKS]
            features[..., : self.state_dim] = (features[..., : self.state_dim] - mean) / std
            return features
        mean, std = self.stats[context]
        return self.encoder.encode((np.asarray(states, dtype=np.float64) - mean) / std, context)

    def flatten_window(self, window: torch.Tensor) -> torch.Tensor:
        """(B, history, encoder.dim) encoded states, oldest first -> (B, input_dim) model input."""
        return torch.cat([window[..., : self.state_dim].flatten(1), window[:, -1, self.state_dim :]], dim=1)

    def to_dict(self) -> dict[str, Any]:
        return {
            "encoder": self.encoder.to_dict(),
            "history": self.history,
            "normalization": {k: {"mean": m.tolist(), "std": s.tolist()} for k, (m, s) in self.stats.items()},
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> BCFeatures:
        return cls(encoder_from_dict(data["encoder"]), data["normalization"], data["history"])
