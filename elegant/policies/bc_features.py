"""Model inputs of the BC policy: normalised, padded states over a short history, plus the task one-hot.

Training and the running policy build inputs with the same two steps, so they cannot drift apart:
`encode` (per-task normalisation, then `TaskFeatureEncoder` padding and one-hot) for each state, and
`flatten_window` for the last `history` encoded states. The window repeats the first state of an episode
until enough steps exist, so the first action sees a full-width input like every other. Normalisation is
per task because the same padded slot holds different objects in different tasks; dimensions that
barely vary in the demos get a floor on their scale so small run-time deviations do not explode.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from annotations import TaskFeatureEncoder
from elegant.policies.bc_data import DemoSet


class BCFeatures:
    """The encoder, per-task normalisation and history length that define a BC model's input."""

    def __init__(self, encoder: TaskFeatureEncoder, stats: Mapping[str, Mapping[str, Any]], history: int) -> None:
        self.encoder = encoder
        self.history = int(history)
        self.stats = {
            k: (np.asarray(v["mean"], dtype=np.float64), np.asarray(v["std"], dtype=np.float64))
            for k, v in stats.items()
        }

    @classmethod
    def fit(cls, data: DemoSet, *, history: int, min_std: float) -> BCFeatures:
        stats = {}
        for key in data.layouts:
            states = np.concatenate([e.states for e in data.episodes if e.task == key])
            stats[key] = {"mean": states.mean(0), "std": np.maximum(states.std(0), min_std)}
        return cls(TaskFeatureEncoder(data.layouts), stats, history)

    @property
    def state_dim(self) -> int:
        return self.encoder.state_dim

    @property
    def input_dim(self) -> int:
        return self.history * self.encoder.state_dim + len(self.encoder.tasks)

    def encode(self, states: np.ndarray, key: str) -> np.ndarray:
        """(..., D_task) raw states of task `key` -> (..., encoder.dim) float32 model features."""
        mean, std = self.stats[key]
        return self.encoder.encode((np.asarray(states, dtype=np.float64) - mean) / std, key)

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
        return cls(TaskFeatureEncoder.from_dict(data["encoder"]), data["normalization"], data["history"])
