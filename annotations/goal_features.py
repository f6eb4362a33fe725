"""A task-agnostic, goal-relative encoding of the low-dimensional state (docs/design.md §4.4).

`TaskFeatureEncoder` pads each task's own state layout and appends a task one-hot, so a model reads only
the tasks it was trained on. This encoding names no task: it reads the state through the episode's goal
(`metadata["goal_geometry"]`, `base_suites.goal_geometry`) and the state layout's entry names, so the
same scene with the same goal gives the same features whatever the task is called, in whatever order
its objects are listed, and a model trained on some tasks scores states of any other it can encode.

Per state, float32, the continuous part first (normalised by the models), then the binary part:

    robot (17)            end effector relative to the robot's base (3), hand quaternion (4), finger
                          joints (2), arm joints (7), end-effector height above the table (1)
    goal slot x 3 (17)    per BDDL goal predicate, in the goal's order: for on/in, the object to move
                          relative to the end effector (3), its up axis (3), its height above the table
                          (1), the destination (an object or a region's centre) relative to the object
                          (3) and to the end effector (3), the region's half-extents (3, zeros for an
                          object), 0; for open/close/turnon/turnoff, the place to act on relative to the
                          end effector (3), zeros (3), its height (1), zeros (9), the progress
                          (q - reference) / (goal - reference) of its joint (1)
    other object x 5 (7)  the nearest other movable objects to the end effector, nearest first: relative
                          position (3), up axis (3), height above the table (1)
    binary                per goal slot: present, predicate one-hot (on, in, open, close, turnon,
                          turnoff), destination is a region (8); per other-object slot: present (1)

Absent slots are zeros. An env this cannot encode (no goal geometry, more than 3 goal predicates, a
goal naming an object the state does not hold) is refused with one line.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from annotations.format import task_key
from base_suites.runtime.errors import UserInputError

ENCODING = "goal-relative"
VERSION = 1
PREDICATES = ("on", "in", "open", "close", "turnon", "turnoff")
ROBOT_PREFIX = [["robot0_eef_pos", 3], ["robot0_eef_quat", 4], ["robot0_gripper_qpos", 2], ["robot0_joint_pos", 7]]
GOAL_SLOTS = 3
OTHER_SLOTS = 5
ROBOT_DIM = 17
GOAL_DIM = 17
OTHER_DIM = 7
GOAL_FLAGS = 2 + len(PREDICATES)


def _rotation(quat: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions (x, y, z, w) -> (..., 3, 3) rotation matrices."""
    q = quat / np.maximum(np.linalg.norm(quat, axis=-1, keepdims=True), 1e-12)
    x, y, z, w = np.moveaxis(q, -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


@dataclass(frozen=True)
class _Place:
    """Where a goal's destination or articulated target is: an object's pose in the state (`pose` = index
    of its position, the quaternion follows), or a fixed world point, or a point fixed to an object."""

    pose: int | None = None  # object in the state: index of its pos
    world: np.ndarray | None = None  # (3,) fixed world position
    local: np.ndarray | None = None  # (3,) offset in the frame of the object at `pose`
    half_size: np.ndarray | None = None

    def position(self, states: np.ndarray) -> np.ndarray:
        if self.world is not None:
            return np.broadcast_to(self.world, states.shape[:-1] + (3,))
        origin = states[..., self.pose : self.pose + 3]
        if self.local is None:
            return origin
        return origin + _rotation(states[..., self.pose + 3 : self.pose + 7]) @ self.local


@dataclass(frozen=True)
class _GoalSlot:
    kind: int  # index in PREDICATES
    subject: int | None  # on/in: index of the moved object's pos in the state
    place: _Place  # on/in: destination; articulation: where to act
    region: bool
    joint: int | None = None  # articulation: index of its joint in the state
    reference: float = 0.0
    goal: float = 1.0


@dataclass(frozen=True)
class GoalContext:
    """One episode's encoding plan: state indices and the goal's fixed geometry (from `check_env`).

    It remembers the last single state it encoded: the members of a critic ensemble bound with one
    context encode each decision's state once (`CriticEnsemble.bind`)."""

    task: str
    state_size: int
    base: np.ndarray
    table_height: float
    goals: tuple[_GoalSlot, ...]
    others: np.ndarray  # indices of the other objects' positions, ordered by name
    last: list = field(default_factory=list, compare=False, repr=False)  # [state bytes, features] or empty


def _slots(layout: list[list[Any]]) -> dict[str, int]:
    """Entry name -> its first index in the state vector."""
    out, at = {}, 0
    for name, size in layout:
        out[str(name)] = at
        at += int(size)
    return out


class GoalFeatureEncoder:
    """Maps (state, episode goal) to one float32 vector of fixed width; see the module docstring.

    `tasks` lists the tasks the model was trained on, for its records; it does not limit what binds."""

    kind = ENCODING

    def __init__(self, tasks: Iterable[str] = ()) -> None:
        self.tasks = sorted(set(tasks))
        self.state_dim = ROBOT_DIM + GOAL_SLOTS * GOAL_DIM + OTHER_SLOTS * OTHER_DIM
        self.dim = self.state_dim + GOAL_SLOTS * GOAL_FLAGS + OTHER_SLOTS

    def check_env(self, metadata: Mapping[str, Any], model_path: str = "model") -> GoalContext:
        """The encoding plan for the env (or demo) `metadata` describes: suite, task_index, state_layout and
        goal_geometry. Refuses (one line) what it cannot encode."""
        key = task_key(metadata["suite"], metadata["task_index"])
        where = f"{model_path}: env task {key}"
        geometry = metadata.get("goal_geometry")
        if not geometry:
            raise UserInputError(
                f"{where} has no goal_geometry (recorded by this version's envs, demos and annotations; "
                "re-annotate older files): the goal-relative encoding needs it"
            )
        if "error" in geometry:
            raise UserInputError(f"{where}: cannot encode its goal: {geometry['error']}")
        if geometry.get("version") != 1:
            raise UserInputError(f"{where}: goal_geometry version {geometry.get('version')!r}; expected 1")
        layout = [[str(n), int(s)] for n, s in metadata["state_layout"]]
        if layout[: len(ROBOT_PREFIX)] != ROBOT_PREFIX:
            raise UserInputError(f"{where}: its state does not start with the robot entries {ROBOT_PREFIX}")
        goal = [list(p) for p in geometry["goal"]]
        if len(goal) > GOAL_SLOTS:
            raise UserInputError(f"{where} has {len(goal)} goal predicates; the encoding holds {GOAL_SLOTS}")
        index = _slots(layout)

        def pose_of(name: str) -> int:
            if f"{name}/pos" not in index or f"{name}/quat" not in index:
                raise UserInputError(f"{where}: its goal names {name!r}, whose pose its state does not hold")
            return index[f"{name}/pos"]

        def place_of(name: str) -> tuple[_Place, bool]:
            region = geometry["regions"].get(name)
            if region is None:
                return _Place(pose=pose_of(name)), False
            half = None if region["half_size"] is None else np.asarray(region["half_size"], dtype=np.float64)
            at = np.asarray(region["position"], dtype=np.float64)
            if region["frame"] == "object":
                return _Place(pose=pose_of(region["parent"]), local=at, half_size=half), True
            return _Place(world=at, half_size=half), True

        roles: set[str] = set()
        slots = []
        for predicate in goal:
            kind, *args = predicate
            if kind not in PREDICATES:
                raise UserInputError(f"{where}: goal predicate {kind!r} is not one of {', '.join(PREDICATES)}")
            if kind in ("on", "in"):
                place, region = place_of(args[1])
                slots.append(_GoalSlot(PREDICATES.index(kind), pose_of(args[0]), place, region))
                roles.update(args[:1] + ([] if region else args[1:]))
                continue
            joint = geometry["articulations"][f"{kind}({args[0]})"]
            entry = f"{joint['entity']}/joints"
            if entry not in index:
                raise UserInputError(f"{where}: its goal moves {joint['entity']}, whose joints its state does not hold")
            place, _ = place_of(args[0])
            slots.append(
                _GoalSlot(
                    PREDICATES.index(kind),
                    None,
                    place,
                    args[0] in geometry["regions"],
                    index[entry] + int(joint["index"]),
                    float(joint["reference"]),
                    float(joint["goal"]),
                )
            )
        objects = sorted(n[: -len("/pos")] for n, _ in layout if n.endswith("/pos"))
        return GoalContext(
            key,
            sum(s for _, s in layout),
            np.asarray(geometry["robot_base"], dtype=np.float64),
            float(geometry["table_height"]),
            tuple(slots),
            np.array([index[f"{n}/pos"] for n in objects if n not in roles], dtype=np.int64),
        )

    def encode(self, states: np.ndarray, context: GoalContext) -> np.ndarray:
        """(..., D) states of the episode `context` plans for -> (..., dim) float32 features (a new array)."""
        s = np.asarray(states, dtype=np.float64)
        if s.shape[-1] != context.state_size:
            raise UserInputError(
                f"task {context.task}: state has {s.shape[-1]} entries; its layout has {context.state_size}"
            )
        if s.size != context.state_size:  # a batch; one state (of any leading shape of ones) is remembered
            return self._encode(s, context)
        key = (s.shape, s.tobytes())
        if not context.last or context.last[0] != key:
            context.last[:] = [key, self._encode(s, context)]
        return context.last[1].copy()

    def _encode(self, s: np.ndarray, context: GoalContext) -> np.ndarray:
        lead = s.shape[:-1]
        eef = s[..., 0:3]
        continuous = [eef - context.base, s[..., 3:16], eef[..., 2:3] - context.table_height]
        flags = []
        zeros3 = np.zeros(lead + (3,))
        for k in range(GOAL_SLOTS):
            slot = context.goals[k] if k < len(context.goals) else None
            if slot is None:
                continuous.append(np.zeros(lead + (GOAL_DIM,)))
                flags.append(np.zeros(lead + (GOAL_FLAGS,)))
                continue
            target = slot.place.position(s)
            half = zeros3 if slot.place.half_size is None else np.broadcast_to(slot.place.half_size, lead + (3,))
            if slot.subject is None:  # an articulation: where to act, and how far the joint has come
                progress = (s[..., slot.joint] - slot.reference) / (slot.goal - slot.reference)
                parts = [target - eef, zeros3, target[..., 2:3] - context.table_height, zeros3, zeros3, half]
                parts.append(progress[..., None])
            else:
                subject = s[..., slot.subject : slot.subject + 3]
                up = _rotation(s[..., slot.subject + 3 : slot.subject + 7])[..., :, 2]
                parts = [subject - eef, up, subject[..., 2:3] - context.table_height]
                parts += [target - subject, target - eef, half, np.zeros(lead + (1,))]
            continuous += parts
            kind = np.zeros(lead + (len(PREDICATES),))
            kind[..., slot.kind] = 1.0
            flags += [np.ones(lead + (1,)), kind, np.full(lead + (1,), float(slot.region))]
        others, present = self._others(s, context, eef)
        features = np.concatenate(continuous + [others] + flags + [present], axis=-1)
        return features.astype(np.float32)

    def _others(self, s: np.ndarray, context: GoalContext, eef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lead = s.shape[:-1]
        n = len(context.others)
        out = np.zeros(lead + (OTHER_SLOTS, OTHER_DIM))
        present = np.zeros(lead + (OTHER_SLOTS,))
        if n:
            pos_index = context.others[:, None] + np.arange(3)
            positions = s[..., pos_index]  # (..., n, 3)
            quats = s[..., pos_index[:, :1] + 3 + np.arange(4)]  # (..., n, 4)
            relative = positions - eef[..., None, :]
            order = np.argsort(np.linalg.norm(relative, axis=-1), axis=-1, kind="stable")[..., :OTHER_SLOTS]
            keep = order.shape[-1]
            pick = order[..., None]
            up = _rotation(np.take_along_axis(quats, pick, axis=-2))[..., :, 2]
            chosen = np.take_along_axis(relative, pick, axis=-2)
            height = np.take_along_axis(positions, pick, axis=-2)[..., 2:3] - context.table_height
            out[..., :keep, :] = np.concatenate([chosen, up, height], axis=-1)
            present[..., :keep] = 1.0
        return out.reshape(lead + (OTHER_SLOTS * OTHER_DIM,)), present

    def to_dict(self) -> dict[str, Any]:
        return {"kind": ENCODING, "version": VERSION, "tasks": list(self.tasks)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> GoalFeatureEncoder:
        if data.get("version") != VERSION:
            raise UserInputError(f"goal-relative encoding version {data.get('version')!r}; this build reads {VERSION}")
        return cls(data.get("tasks", ()))
