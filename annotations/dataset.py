"""Reading and writing demonstration files in the layout of `annotations.format`.

Writing is crash-safe and resumable: demos go to `<out>.partial`, flushed after each demo, and the
file is renamed to `<out>` only when the writer is closed as complete. A resumed writer reopens the
partial file and continues after the demos it already holds.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import h5py
import numpy as np

from annotations.format import CRITERIA, FORMAT_VERSION, demo_index, demo_name, task_key
from base_suites.runtime.errors import UserInputError

_JSON_ATTRS = ("knobs", "knob_events", "perturbation", "violated", "fixture_layout", "rollout", "explored_steps")


@dataclass
class Demo:
    """One episode as stored on disk (labels are None in a file that is not annotated)."""

    name: str
    actions: np.ndarray
    states: np.ndarray
    obs: np.ndarray
    next_obs: np.ndarray
    rewards: np.ndarray
    dones: np.ndarray
    attrs: dict[str, Any] = field(default_factory=dict)
    itc: dict[str, np.ndarray] | None = None
    itc_segments: dict[str, np.ndarray] | None = None
    elegance_reward: np.ndarray | None = None
    mc_return: np.ndarray | None = None
    final_state: np.ndarray | None = None  # the MuJoCo state after the last action, where recorded

    @property
    def task_key(self) -> str:
        return task_key(self.attrs["suite"], self.attrs["task_index"])

    @property
    def num_samples(self) -> int:
        return int(self.actions.shape[0])

    @property
    def annotated(self) -> bool:
        return self.itc is not None


def _decode(value: Any) -> Any:
    if isinstance(value, bytes):
        value = value.decode()
    if isinstance(value, np.generic):
        value = value.item()
    return value


def read_attrs(node: h5py.HDFObject) -> dict[str, Any]:
    out = {}
    for key, value in node.attrs.items():
        value = _decode(value)
        if key in _JSON_ATTRS or key in ("env_args", "problem_info", "state_layouts", "annotation", "collection"):
            try:
                value = json.loads(value) if isinstance(value, str) else value
            except json.JSONDecodeError:
                pass
        out[key] = value
    return out


def _write_attrs(node: h5py.HDFObject, attrs: Mapping[str, Any]) -> None:
    for key, value in attrs.items():
        node.attrs[key] = json.dumps(value) if isinstance(value, (dict, list, tuple)) else value


class DemoFile:
    """A demos file opened for reading; validates the layout version and required fields."""

    def __init__(self, path: str | os.PathLike, *, require_labels: bool = False) -> None:
        self.path = str(path)
        if not os.path.exists(self.path):
            raise UserInputError(f"{self.path}: no such file")
        try:
            self._h5 = h5py.File(self.path, "r")
        except OSError as exc:
            raise UserInputError(f"{self.path}: not a readable HDF5 file ({exc.__class__.__name__})") from None
        if "data" not in self._h5:
            raise UserInputError(f"{self.path}: missing group 'data' (expected LIBERO's robomimic layout)")
        self.attrs = read_attrs(self._h5["data"])
        version = self.attrs.get("format_version")
        if version is not None and str(version).split("/")[0] != FORMAT_VERSION.split("/")[0]:
            raise UserInputError(f"{self.path}: data.format_version is {version!r}, expected {FORMAT_VERSION!r}")
        if version is not None and str(version) != FORMAT_VERSION:
            raise UserInputError(
                f"{self.path}: data.format_version {version!r} is not supported; expected {FORMAT_VERSION!r}"
            )
        self.names = sorted((n for n in self._h5["data"] if n.startswith("demo_")), key=demo_index)
        if require_labels and not self.annotated:
            raise UserInputError(f"{self.path}: no ITC labels (data.annotation missing); run `elegant annotate` first")

    @property
    def annotated(self) -> bool:
        return "annotation" in self.attrs

    @property
    def state_layouts(self) -> dict[str, list]:
        return dict(self.attrs.get("state_layouts", {}))

    def __len__(self) -> int:
        return len(self.names)

    def __iter__(self) -> Iterator[Demo]:
        for name in self.names:
            yield self.demo(name)

    def demo(self, name: str) -> Demo:
        g = self._h5["data"][name]
        for key in ("actions", "states", "obs/state", "next_obs/state", "rewards", "dones"):
            if key not in g:
                raise UserInputError(f"{self.path}: data/{name} has no field '{key}'")
        demo = Demo(
            name=name,
            actions=g["actions"][()],
            states=g["states"][()],
            obs=g["obs/state"][()],
            next_obs=g["next_obs/state"][()],
            rewards=g["rewards"][()],
            dones=g["dones"][()],
            attrs=read_attrs(g),
            final_state=g["final_state"][()] if "final_state" in g else None,
        )
        if "itc" in g:
            missing = [c for c in CRITERIA if c not in g["itc"]]
            if missing:
                raise UserInputError(f"{self.path}: data/{name}/itc lacks criteria {missing}")
            demo.itc = {c: g["itc"][c][()].astype(bool) for c in CRITERIA}
            demo.itc_segments = {c: g["itc_segments"][c][()].astype(bool) for c in CRITERIA}
            demo.elegance_reward = g["elegance_reward"][()]
            demo.mc_return = g["mc_return"][()]
        elif self.annotated:
            raise UserInputError(f"{self.path}: data/{name} has no 'itc' labels although the file is annotated")
        return demo

    def close(self) -> None:
        self._h5.close()

    def __enter__(self) -> DemoFile:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class DemoWriter:
    """Appends demos to `<path>.partial` and renames it to `path` on `finish()`."""

    def __init__(self, path: str | os.PathLike, file_attrs: Mapping[str, Any], *, resume: bool = False) -> None:
        self.path = str(path)
        self.partial = self.path + ".partial"
        if resume and os.path.exists(self.partial):
            self._h5 = h5py.File(self.partial, "a")
        else:
            if os.path.exists(self.partial):
                os.remove(self.partial)
            os.makedirs(os.path.dirname(os.path.abspath(self.path)), exist_ok=True)
            self._h5 = h5py.File(self.partial, "w")
            data = self._h5.create_group("data")
            _write_attrs(data, {"format_version": FORMAT_VERSION, "total": 0, "state_layouts": {}, **file_attrs})
        self._data = self._h5["data"]
        self._layouts = read_attrs(self._data).get("state_layouts", {})

    @property
    def attrs(self) -> dict[str, Any]:
        """The file's `data` attributes as written so far (a resumed file's are the first run's)."""
        return read_attrs(self._data)

    @property
    def count(self) -> int:
        """How many complete demos the file already holds (where a resumed run continues)."""
        return sum(1 for n in self._data if n.startswith("demo_"))

    def write_file_attrs(self, attrs: Mapping[str, Any]) -> None:
        _write_attrs(self._data, attrs)

    def append(self, demo: Demo, state_layout: list | None = None) -> str:
        """Write one demo (its name is assigned here) and flush it to disk."""
        name = demo_name(self.count)
        tmp = "_incomplete_" + name
        if tmp in self._data:
            del self._data[tmp]
        g = self._data.create_group(tmp)
        g.create_dataset("actions", data=np.asarray(demo.actions, dtype=np.float64))
        g.create_dataset("states", data=np.asarray(demo.states, dtype=np.float64))
        g.create_dataset("obs/state", data=np.asarray(demo.obs, dtype=np.float32))
        g.create_dataset("next_obs/state", data=np.asarray(demo.next_obs, dtype=np.float32))
        g.create_dataset("rewards", data=np.asarray(demo.rewards, dtype=np.float32))
        g.create_dataset("dones", data=np.asarray(demo.dones, dtype=np.uint8))
        if demo.final_state is not None:
            g.create_dataset("final_state", data=np.asarray(demo.final_state, dtype=np.float64))
        if demo.itc is not None:
            for c in CRITERIA:
                g.create_dataset(f"itc/{c}", data=np.asarray(demo.itc[c], dtype=bool))
                g.create_dataset(f"itc_segments/{c}", data=np.asarray(demo.itc_segments[c], dtype=bool))
            g.create_dataset("elegance_reward", data=np.asarray(demo.elegance_reward, dtype=np.float32))
            g.create_dataset("mc_return", data=np.asarray(demo.mc_return, dtype=np.float32))
        _write_attrs(g, {**demo.attrs, "num_samples": int(len(demo.actions))})
        self._data.move(tmp, name)
        if state_layout is not None and demo.task_key not in self._layouts:
            self._layouts[demo.task_key] = state_layout
            _write_attrs(self._data, {"state_layouts": self._layouts})
        self._data.attrs["total"] = int(self._data.attrs["total"]) + len(demo.actions)
        self._h5.flush()
        return name

    def finish(self) -> str:
        """Close and atomically publish the file."""
        for n in list(self._data):
            if n.startswith("_incomplete_"):
                del self._data[n]
        self._h5.close()
        os.replace(self.partial, self.path)
        return self.path

    def abandon(self) -> None:
        """Close without publishing (the partial file stays for --resume)."""
        self._h5.close()
