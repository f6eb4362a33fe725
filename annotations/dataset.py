"""Reading and writing demonstration files in the layout of `annotations.format`.

Writing is crash-safe and resumable (`DemoWriter`): each finished demo is durable on its own in the
journal folder `<out>.partial/`, and `<out>` appears, assembled and read back, only when all are
there. A resumed writer continues after the demos the journal holds.
"""

from __future__ import annotations

import io
import json
import os
import shutil
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import h5py
import numpy as np

from annotations.format import CRITERIA, FORMAT_VERSION, demo_index, demo_name, task_key
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import atomic_write
from base_suites.runtime.locks import output_lock
from base_suites.stack import SIMULATOR_FIELDS, stack_mismatch, stack_record

_JSON_ATTRS = (
    "knobs",
    "knob_events",
    "perturbation",
    "violated",
    "fixture_layout",
    "goal_geometry",
    "rollout",
    "explored_steps",
)


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
        if key in _JSON_ATTRS or key in (
            "env_args",
            "problem_info",
            "state_layouts",
            "state_layout",
            "annotation",
            "collection",
            "stack",
        ):
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
    """A demos file opened for reading; validates the layout version and required fields. `image`: read
    these bytes (a whole file, e.g. one assembled in memory) instead of the file at `path`, which then
    only names it in messages."""

    def __init__(self, path: str | os.PathLike, *, require_labels: bool = False, image: bytes | None = None) -> None:
        self.path = str(path)
        if image is None and not os.path.exists(self.path):
            raise UserInputError(f"{self.path}: no such file")
        try:
            self._h5 = h5py.File(self.path if image is None else io.BytesIO(image), "r")
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

    def validate(self) -> None:
        """Read every demo once (each read checks shapes, lengths and finiteness), so that a command
        refuses a bad file before any work starts rather than at that demo."""
        for name in self.names:
            self.demo(name)

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
        _check_arrays(f"{self.path}: data/{name}", demo)
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


def _check_arrays(where: str, demo: Demo) -> None:
    """Refuse a demo whose arrays disagree in length or hold NaN or infinity (which would train a NaN
    model or corrupt labels downstream), naming the field and the first bad step."""
    steps = demo.actions.shape[0] if demo.actions.ndim == 2 else -1
    if demo.actions.ndim != 2 or demo.actions.shape[1] != 7:
        raise UserInputError(f"{where}/actions has shape {demo.actions.shape}; expected (steps, 7)")
    fields = {
        "states": demo.states,
        "obs/state": demo.obs,
        "next_obs/state": demo.next_obs,
        "rewards": demo.rewards,
        "dones": demo.dones,
    }
    for key, values in fields.items():
        if values.ndim == 0 or values.shape[0] != steps:
            raise UserInputError(f"{where}/{key} has shape {values.shape}; expected {steps} steps like actions")
    for key, values in {"actions": demo.actions, **fields}.items():
        bad = ~np.isfinite(values.reshape(steps, -1)).all(axis=1)
        if bad.any():
            raise UserInputError(f"{where}/{key} holds NaN or infinity (first at step {int(np.argmax(bad))})")


class DemoWriter:
    """Writes a demo file so that a kill or a full disk loses at most the demo in flight.

    Each appended demo becomes durable on its own: a small HDF5 file in the journal directory
    `<path>.partial/` (written under a temporary name, synced, renamed), beside `header.h5` with the
    file's attributes. `finish()` assembles the journal into the final file under a temporary name,
    reads every demo of it back, and only then renames it to `path` and removes the journal; a kill
    during assembly leaves the journal whole. `resume=True` continues after the demos the journal holds
    (a demo file that does not read back, e.g. cut off by a full disk, is dropped and written again).
    The writer holds the output's lock (`base_suites.runtime.locks`) until `finish()` or `abandon()`,
    so a second writer of the same file is refused."""

    def __init__(self, path: str | os.PathLike, file_attrs: Mapping[str, Any], *, resume: bool = False) -> None:
        self.path = os.fspath(path)
        self.partial = self.path + ".partial"
        os.makedirs(os.path.dirname(os.path.abspath(self.path)), exist_ok=True)
        self._lock = output_lock(self.path)
        self._lock.__enter__()
        try:
            if os.path.isfile(self.partial):  # a single-file partial of an earlier version
                if resume:
                    raise UserInputError(
                        f"{self.partial}: an interrupted file of an earlier libero-elegant, which cannot be "
                        "resumed; delete it and run again without --resume"
                    )
                os.remove(self.partial)
            if resume and self.resumable(self.path):
                self._refuse_another_stack()
                self._count = self._recover()
            else:
                if os.path.isdir(self.partial):
                    shutil.rmtree(self.partial)
                os.makedirs(self.partial)
                header = {"format_version": FORMAT_VERSION, "state_layouts": {}, **file_attrs}
                self._write_header({**header, "stack": stack_record(render=None)})  # this file's, not its source's
                self._count = 0
        except BaseException:
            self._lock.__exit__(None, None, None)
            raise

    def _refuse_another_stack(self) -> None:
        """A journal begun on another simulator stack (docs/design.md §4.5) is not continued: its episodes
        and the ones this stack would add could not stand in one file."""
        recorded = self.attrs.get("stack")
        mismatch = stack_mismatch(recorded, stack_record(render=None), SIMULATOR_FIELDS) if recorded else None
        if mismatch:
            field, begun, now = mismatch
            raise UserInputError(
                f"{self.partial}: begun with {field} {begun!r} but this stack has {now!r}; resume it on the "
                "stack it began on, or delete it and start again"
            )

    @staticmethod
    def resumable(path: str | os.PathLike) -> bool:
        """Whether an interrupted writer of `path` left a journal to resume (its header is written, and
        durable, before any demo; a journal without one holds nothing and starts afresh)."""
        return _reads(os.path.join(os.fspath(path) + ".partial", _HEADER), read_attrs)

    @property
    def attrs(self) -> dict[str, Any]:
        """The file's `data` attributes as written so far (a resumed file's are the first run's)."""
        with h5py.File(os.path.join(self.partial, _HEADER), "r") as h5:
            return read_attrs(h5)

    @property
    def count(self) -> int:
        """How many complete demos the file already holds (where a resumed run continues)."""
        return self._count

    def written_attrs(self) -> Iterator[dict[str, Any]]:
        """The attributes of the demos written so far, in order."""
        for i in range(self._count):
            with h5py.File(self._episode_path(i), "r") as h5:
                yield read_attrs(h5["demo"])

    def write_file_attrs(self, attrs: Mapping[str, Any]) -> None:
        self._write_header({**self.attrs, **attrs})

    def append(self, demo: Demo, state_layout: list | None = None) -> str:
        """Write one demo (its name is assigned here) durably to the journal."""
        name = demo_name(self._count)
        _check_arrays(f"{self.path}: {name}", demo)

        def fill(h5: h5py.File) -> None:
            g = h5.create_group("demo")
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
            if state_layout is not None:
                _write_attrs(h5, {"task_key": demo.task_key, "state_layout": state_layout})

        atomic_write(self._episode_path(self._count), _h5_image(fill))
        self._count += 1
        return name

    def finish(self) -> str:
        """Assemble the journal into the final file in memory, read every demo of it back, publish it
        (atomically) and remove the journal."""
        try:
            attrs = self.attrs
            layouts = dict(attrs.get("state_layouts") or {})

            def assemble(out: h5py.File) -> None:
                data = out.create_group("data")
                total = 0
                for i in range(self._count):
                    with h5py.File(self._episode_path(i), "r") as episode:
                        episode.copy(episode["demo"], data, name=demo_name(i))
                        total += int(episode["demo"].attrs["num_samples"])
                        extra = read_attrs(episode)
                        if "state_layout" in extra:
                            layouts.setdefault(extra["task_key"], extra["state_layout"])
                _write_attrs(data, {**attrs, "total": total, "state_layouts": layouts})

            image = _h5_image(assemble)
            with DemoFile(self.path, image=image) as check:  # every dataset of every demo reads back
                if len(check) != self._count:
                    raise OSError(f"{self.path}: {len(check)} demos read back, {self._count} written")
                check.validate()
            atomic_write(self.path, image)
            shutil.rmtree(self.partial)
            return self.path
        finally:
            self._lock.__exit__(None, None, None)

    def abandon(self) -> None:
        """Stop without publishing (the journal stays for --resume)."""
        self._lock.__exit__(None, None, None)

    def discard(self) -> None:
        """Stop without publishing and remove the journal (for writers that are never resumed)."""
        try:
            shutil.rmtree(self.partial, ignore_errors=True)
        finally:
            self._lock.__exit__(None, None, None)

    def _episode_path(self, i: int) -> str:
        return os.path.join(self.partial, f"{demo_name(i)}.h5")

    def _write_header(self, attrs: Mapping[str, Any]) -> None:
        atomic_write(os.path.join(self.partial, _HEADER), _h5_image(lambda h5: _write_attrs(h5, attrs)))

    def _recover(self) -> int:
        """Count the journal's readable demos from demo_0 on; drop everything after the first gap."""
        count = 0
        while _reads(self._episode_path(count), lambda h5: h5["demo"].attrs["num_samples"]):
            count += 1
        keep = {_HEADER} | {os.path.basename(self._episode_path(i)) for i in range(count)}
        for leftover in set(os.listdir(self.partial)) - keep:
            os.remove(os.path.join(self.partial, leftover))
        return count


_HEADER = "header.h5"


def _h5_image(fill: Callable[[h5py.File], None]) -> bytes:
    """The bytes of an HDF5 file that `fill` writes, built in memory: the file reaches the disk only through
    `atomic_write`, whole or not at all, and a full disk is a plain OSError there (HDF5 failing a write of
    its own can crash the interpreter)."""
    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as h5:
        fill(h5)
    return buffer.getvalue()


def _reads(path: str, probe: Callable[[h5py.File], Any]) -> bool:
    """Whether the HDF5 file at `path` exists, opens and answers `probe`."""
    try:
        with h5py.File(path, "r") as h5:
            probe(h5)
        return True
    except (OSError, KeyError):
        return False
