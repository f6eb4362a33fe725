"""Demonstrations for behaviour cloning: (task, observed states, actions) per episode, checked on load.

BC needs only the env's low-dimensional `obs/state` and `actions`, so unannotated demo files are fine.
Files may hold several tasks; the state layout of each task comes from the file's `state_layouts` and
must agree across files, because the policy will refuse envs whose layout differs from it.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from annotations import DemoFile
from base_suites.runtime.errors import UserInputError
from elegant.policies.protocol import ACTION_DIM


@dataclass
class Episode:
    task: str
    states: np.ndarray  # (T, D_task) float64
    actions: np.ndarray  # (T, 7) float32
    metadata: dict = field(default_factory=dict)  # as env.metadata: suite, task_index, state_layout, goal_geometry
    source: str = ""  # "FILE: data/demo_i", for messages


@dataclass
class DemoSet:
    layouts: dict[str, list] = field(default_factory=dict)
    episodes: list[Episode] = field(default_factory=list)
    files: list[dict] = field(default_factory=list)  # per file: path, demos, samples (identifies the data on resume)

    @property
    def num_samples(self) -> int:
        return sum(len(e.actions) for e in self.episodes)


def load_demos(paths: Sequence[str | os.PathLike], successful_only: bool = False) -> DemoSet:
    """Read every demo of every file, refusing missing layouts, layout conflicts and shape mismatches.

    `successful_only` skips demos whose `success` attribute is false (demos without one, such as
    LIBERO's own, count as successful): LIBERO's datasets hold successful demos only, and a mixed
    expert's failed episodes (a `misplace` let go beside the goal) would teach the policy to fail."""
    if isinstance(paths, (str, os.PathLike)) or not paths:
        raise UserInputError("train_policy: expected a non-empty list of demo files")
    data = DemoSet()
    for path in paths:
        with DemoFile(path) as f:
            samples = 0
            for name, layout in f.state_layouts.items():
                layout = [[str(n), int(s)] for n, s in layout]
                if data.layouts.setdefault(name, layout) != layout:
                    raise UserInputError(
                        f"{f.path}: data.state_layouts[{name!r}] differs from the layout of the same task in an "
                        "earlier file"
                    )
            for demo in f:
                key = demo.task_key
                if key not in f.state_layouts:
                    raise UserInputError(
                        f"{f.path}: data.state_layouts has no entry for task {key!r} of data/{demo.name}"
                    )
                width = sum(s for _, s in data.layouts[key])
                where = f"{f.path}: data/{demo.name}"
                if demo.obs.ndim != 2 or demo.obs.shape[1] != width:
                    raise UserInputError(
                        f"{where}/obs/state has shape {demo.obs.shape}; expected (T, {width}) from the layout of {key}"
                    )
                if demo.actions.shape != (len(demo.obs), ACTION_DIM):
                    raise UserInputError(
                        f"{where}/actions has shape {demo.actions.shape}; expected ({len(demo.obs)}, {ACTION_DIM})"
                    )
                if len(demo.obs) == 0 or (successful_only and not bool(demo.attrs.get("success", True))):
                    continue
                metadata = {
                    "suite": demo.attrs["suite"],
                    "task_index": demo.attrs["task_index"],
                    "state_layout": data.layouts[key],
                    "goal_geometry": demo.attrs.get("goal_geometry"),
                }
                data.episodes.append(
                    Episode(key, demo.obs.astype(np.float64), demo.actions.astype(np.float32), metadata, where)
                )
                samples += len(demo.obs)
            data.files.append({"path": os.path.abspath(f.path), "demos": len(f), "samples": samples})
    if not data.episodes:
        raise UserInputError(f"{', '.join(map(str, paths))}: no demo with at least one step")
    used = {e.task for e in data.episodes}
    data.layouts = {k: v for k, v in data.layouts.items() if k in used}  # the policy knows only tasks it saw
    return data
