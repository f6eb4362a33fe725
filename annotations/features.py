"""Fixed-width model inputs from task-specific state layouts.

Each LIBERO task has its own low-dimensional state layout (its own objects). Multi-task models (the BC
policy, the critic) take the state zero-padded to the widest layout they were trained on, followed by
a one-hot of the task ("task-onehot"). The encoder remembers the exact layout of every task it knows, so
a model can refuse an env whose layout differs instead of silently reading the wrong numbers. The other
encoding, "goal-relative" (`annotations.goal_features`), names no task and binds to any it can encode.

Both answer `check_env(metadata) -> context` (refusing with one line) and `encode(states, context)`;
`state_dim` leading entries of their features are continuous (normalised by the models), the rest binary.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal, get_args

import numpy as np

from annotations.format import task_key
from annotations.goal_features import GoalFeatureEncoder
from base_suites.runtime.errors import UserInputError, unknown_choice

Encoding = Literal["task-onehot", "goal-relative"]
ENCODINGS: tuple[str, ...] = get_args(Encoding)


class TaskFeatureEncoder:
    """Maps (state, task) to one float32 vector: padded state then task one-hot."""

    kind = "task-onehot"

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


FeatureEncoder = TaskFeatureEncoder | GoalFeatureEncoder


def make_encoder(encoding: str, layouts: Mapping[str, list[list[Any]]]) -> FeatureEncoder:
    """The encoder `encoding` names, for models trained on the tasks of `layouts` ({task key: state layout})."""
    if encoding == "task-onehot":
        return TaskFeatureEncoder(layouts)
    if encoding == "goal-relative":
        if not layouts:
            raise UserInputError("no tasks to encode: the dataset holds no demos")
        return GoalFeatureEncoder(layouts)
    raise unknown_choice("encoding", encoding, ENCODINGS)


def encoder_from_dict(data: Mapping[str, Any]) -> FeatureEncoder:
    """The encoder a saved model recorded (`to_dict`); models from before the goal encoding hold layouts."""
    if data.get("kind", "task-onehot") == "goal-relative":
        return GoalFeatureEncoder.from_dict(data)
    return TaskFeatureEncoder.from_dict(data)
