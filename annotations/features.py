"""Fixed-width model inputs from task-specific state layouts.

Each LIBERO task has its own low-dimensional state layout (its own objects). Multi-task models (the BC
policy, the critic) take the state zero-padded to the widest layout they were trained on, followed by
a one-hot of the task. The encoder remembers the exact layout of every task it knows, so a model can
refuse an env whose layout differs instead of silently reading the wrong numbers.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from annotations.format import task_key
from base_suites.runtime.errors import UserInputError


class TaskFeatureEncoder:
    """Maps (state, task) to one float32 vector: padded state then task one-hot."""

    def __init__(self, layouts: Mapping[str, list[list[Any]]]) -> None:
        if not layouts:
            raise UserInputError("no tasks to encode: the dataset holds no demos")
        self.layouts = {k: [[str(n), int(s)] for n, s in v] for k, v in sorted(layouts.items())}
        self.tasks = list(self.layouts)
        self.state_dim = max(sum(s for _, s in lay) for lay in self.layouts.values())
        self.dim = self.state_dim + len(self.tasks)

    def task_id(self, key: str) -> int:
        try:
            return self.tasks.index(key)
        except ValueError:
            raise UserInputError(
                f"task {key!r} is not among the tasks this model was trained on: {', '.join(self.tasks)}"
            ) from None

    def check_env(self, metadata: Mapping[str, Any], model_path: str = "model") -> str:
        """Return the env's task key, refusing an unknown task or a different state layout."""
        key = task_key(metadata["suite"], metadata["task_index"])
        if key not in self.layouts:
            raise UserInputError(
                f"{model_path}: env task {key!r} is not among the tasks the model was trained on: "
                f"{', '.join(self.tasks)}"
            )
        got = [[str(n), int(s)] for n, s in metadata["state_layout"]]
        if got != self.layouts[key]:
            raise UserInputError(
                f"{model_path}: observation layout of env task {key} differs from the one the model was trained on "
                f"(env has {sum(s for _, s in got)} dims, model expects {sum(s for _, s in self.layouts[key])})"
            )
        return key

    def encode(self, states: np.ndarray, key: str | np.ndarray) -> np.ndarray:
        """Encode (..., D_task) states of one task (a key) or of many (an array of task ids)."""
        states = np.asarray(states, dtype=np.float32)
        out = np.zeros(states.shape[:-1] + (self.dim,), dtype=np.float32)
        out[..., : states.shape[-1]] = states
        ids = np.full(states.shape[:-1], self.task_id(key)) if isinstance(key, str) else np.asarray(key)
        np.put_along_axis(out, (self.state_dim + ids)[..., None].astype(np.int64), 1.0, axis=-1)
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"layouts": self.layouts}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TaskFeatureEncoder:
        return cls(data["layouts"])
