"""One step's view of the scene, shared by the four constraints.

Each constraint asks for contacts, the held object, poses and predicates; asking the simulator once per
step and caching the answers here keeps the monitor's cost to one contact pass plus a few array reads
(the budget is 10% of an env step).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from functools import cached_property

import numpy as np

from base_suites.sim_view import GRIPPER, ROBOT, Contact, Region, SimView

ROBOT_PARTS = frozenset((ROBOT, GRIPPER))
# Finger gap (m) below which the gripper is closed on nothing: closed fingers pushing a box touch it with
# both fingers, which SimView.held_object() would call a grasp.
CLOSED_GRIPPER = 0.005


def angle_between(a: np.ndarray, b: np.ndarray) -> float:
    """Angle in radians between two vectors (plain floats: this runs many times per step)."""
    ax, ay, az = float(a[0]), float(a[1]), float(a[2])
    bx, by, bz = float(b[0]), float(b[1]), float(b[2])
    norms = math.sqrt((ax * ax + ay * ay + az * az) * (bx * bx + by * by + bz * bz))
    return math.acos(max(-1.0, min(1.0, (ax * bx + ay * by + az * bz) / norms)))


def up_axis(rotation: np.ndarray) -> np.ndarray:
    """The signed local axis (as a unit vector in the body frame) that points most nearly world-up.

    LIBERO meshes disagree on which local axis is "up" (the grocery items stand on their local y), so
    an object's up axis is read from how it stands, not assumed to be z.
    """
    world_z = rotation[2]  # world-z component of each local axis
    i = int(np.argmax(np.abs(world_z)))
    axis = np.zeros(3)
    axis[i] = np.sign(world_z[i]) or 1.0
    return axis


class RestTracker:
    """Which objects are at rest now, and which have been since the episode began.

    LIBERO's shipped init states are not at rest and the env's settle phase is not always long enough
    (in libero_10's living-room scenes bottles pop out of the table and are still falling when the
    episode starts), so objects are judged only once they have come to rest: `steps` consecutive steps
    below `speed`, which a flying object passing the top of its arc does not fake.
    """

    def __init__(self, ctx: StepContext, names: tuple[str, ...], speed: float, steps: int) -> None:
        self.names, self.speed, self.steps = names, speed, steps
        self._count = {n: steps if ctx.speed(n) < speed else 0 for n in names}  # the env has just settled
        self.settled: set[str] = {n for n in names if self._count[n] >= steps}

    def update(self, ctx: StepContext) -> None:
        for name in self.names:
            self._count[name] = self._count[name] + 1 if ctx.speed(name) < self.speed else 0
            if self._count[name] >= self.steps:
                self.settled.add(name)

    def at_rest(self, name: str) -> bool:
        return self._count[name] >= self.steps


class StepContext:
    """Lazily cached simulator queries for the state after one step."""

    def __init__(self, sim: SimView, known: Mapping[tuple[str, ...], bool] | None = None) -> None:
        """`known`: predicates whose truth at this step is given (see `ITCMonitor.step`'s `goal_reached`)."""
        self.sim = sim
        self._positions: dict[str, np.ndarray] = {}
        self._rotations: dict[str, np.ndarray] = {}
        self._speeds: dict[str, float] = {}
        self._predicates: dict[tuple[str, ...], bool] = dict(known or {})
        self._regions: dict[str, Region] = {}

    @cached_property
    def contacts(self) -> list[Contact]:
        """The step's one contact pass."""
        return self.sim.contacts()

    @cached_property
    def pair_forces(self) -> dict[frozenset[str], float]:
        """Total normal force (N) per pair of entities in contact."""
        forces: dict[frozenset[str], float] = {}
        for c in self.contacts:
            key = frozenset((c.entity_a, c.entity_b))
            forces[key] = forces.get(key, 0.0) + c.normal_force
        return forces

    @cached_property
    def touching(self) -> dict[str, set[str]]:
        """Entity -> the entities it touches."""
        out: dict[str, set[str]] = {}
        for pair in self.pair_forces:
            a, b = tuple(pair)
            out.setdefault(a, set()).add(b)
            out.setdefault(b, set()).add(a)
        return out

    def touches(self, entity: str) -> set[str]:
        return self.touching.get(entity, set())

    def touches_robot(self, entity: str) -> bool:
        return not ROBOT_PARTS.isdisjoint(self.touches(entity))

    @cached_property
    def held(self) -> str | None:
        """The object in the gripper, if the fingers are held apart by it (see CLOSED_GRIPPER)."""
        return self.sim.held_object() if self.sim.gripper_opening() > CLOSED_GRIPPER else None

    @cached_property
    def eef_rotation(self) -> np.ndarray:
        return self.sim.eef_rotation()

    def position(self, name: str) -> np.ndarray:
        if name not in self._positions:
            self._positions[name] = self.sim.position(name)
        return self._positions[name]

    def rotation(self, name: str) -> np.ndarray:
        if name not in self._rotations:
            self._rotations[name] = self.sim.rotation(name)
        return self._rotations[name]

    def speed(self, name: str) -> float:
        if name not in self._speeds:
            v = self.sim.velocity(name)
            self._speeds[name] = math.sqrt(float(v[0]) ** 2 + float(v[1]) ** 2 + float(v[2]) ** 2)
        return self._speeds[name]

    def predicate(self, predicate: tuple[str, ...]) -> bool:
        if predicate not in self._predicates:
            self._predicates[predicate] = self.sim.predicate(predicate)
        return self._predicates[predicate]

    def region(self, name: str) -> Region:
        if name not in self._regions:
            self._regions[name] = self.sim.region(name)
        return self._regions[name]

    def tilt_of(self, name: str, axis: np.ndarray) -> float:
        """Angle (rad) between world up and the object's local unit `axis` as it points now."""
        return math.acos(max(-1.0, min(1.0, float(self.rotation(name)[2] @ axis))))
