"""Where a task's goal lies in one episode's scene: what a task-agnostic state encoding needs beside the state.

The low-dimensional state (`LiberoEnv.state_vector`) holds the robot, every movable object's pose and the
articulated joints, but not the goal's regions: those are sites on the table, on a fixture (placed anew
on each reset, `fixture_layout`) or on a movable object (a basket's inside). `goal_geometry` records,
for the goal of the current episode, as plain JSON:

    goal          the BDDL goal predicates, e.g. [["on", "akita_black_bowl_1", "plate_1"]]
    robot_base    world position of the robot's base (the frame the arm works in)
    table_height  height of the workspace surface
    regions       per goal region: {"frame": "world" | "object", "parent": entity or null, "position",
                  "rotation" (3x3, row-major), "half_size" (or null)}. A region on a movable object is
                  given in that object's frame (it moves with it); any other in world coordinates, as it
                  stands at the episode's start (a drawer's region travels with the drawer by its few
                  centimetres: its joint is in the state).
    articulations per articulation goal target (a drawer region, a door, a knob): {"entity", "index" (the
                  joint within the entity's `<entity>/joints` state entry), "reference", "goal"}: the
                  middle of the range the goal leaves and of the one it reaches (LIBERO's open/close or
                  turn-on/turn-off ranges), so progress = (q - reference) / (goal - reference).

The encoding that reads it is `annotations.goal_features` (docs/design.md §4.4).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from base_suites.runtime.errors import UserInputError
from base_suites.sim_view import SimView

GEOMETRY_VERSION = 1
PLACE_PREDICATES = ("on", "in")
# the range an articulation predicate reaches, and the one it leaves, in LIBERO's articulation properties
_RANGES = {
    "open": ("default_open_ranges", "default_close_ranges"),
    "close": ("default_close_ranges", "default_open_ranges"),
    "turnon": ("default_turnon_ranges", "default_turnoff_ranges"),
    "turnoff": ("default_turnoff_ranges", "default_turnon_ranges"),
}
ARTICULATION_PREDICATES = tuple(_RANGES)


def _place(sim: SimView, name: str) -> dict[str, Any]:
    """A goal region, or an articulated entity that is no region (a door, a knob): where it stands."""
    if name in sim.regions:
        region = sim.region(name)
        parent, position, rotation, half = region.parent, region.centre, region.rotation, region.half_size
    else:
        parent, position, rotation, half = name, sim.position(name), sim.rotation(name), None
    frame = "world"
    if parent in sim.objects:  # rides on a movable object: keep it in that object's frame
        origin, axes = sim.position(parent), sim.rotation(parent)
        position, rotation, frame = axes.T @ (position - origin), axes.T @ rotation, "object"
    return {
        "frame": frame,
        "parent": parent,
        "position": [float(v) for v in position],
        "rotation": [float(v) for v in np.asarray(rotation).reshape(9)],
        "half_size": None if half is None else [float(v) for v in half],
    }


def _articulation(sim: SimView, predicate: str, target: str) -> dict[str, Any]:
    joints = sim.articulation_joints(target)
    entity = next((e for e, js in sim.articulated.items() if joints and joints[0] in js), None)
    if entity is None:
        raise UserInputError(f"goal {predicate}({target}): no articulated joint moves it")
    ranges = sim.articulation_ranges(entity)
    reach, leave = (ranges.get(k) or [] for k in _RANGES[predicate])
    if not reach or not leave:
        raise UserInputError(f"goal {predicate}({target}): {entity} has no {_RANGES[predicate][0]} to measure it")
    return {
        "entity": entity,
        "index": sim.articulated[entity].index(joints[0]),
        "reference": float(np.mean(leave)),
        "goal": float(np.mean(reach)),
    }


def goal_geometry(sim: SimView, goal: list[list[str]] | tuple[tuple[str, ...], ...]) -> dict[str, Any]:
    """The goal's geometry in the scene `sim` shows now (see module doc); a predicate of another kind is
    refused with one line."""
    regions: dict[str, Any] = {}
    articulations: dict[str, Any] = {}
    for predicate in goal:
        kind, *args = predicate
        if kind in PLACE_PREDICATES and len(args) == 2:
            if args[1] in sim.regions:
                regions[args[1]] = _place(sim, args[1])
        elif kind in ARTICULATION_PREDICATES and len(args) == 1:
            articulations[f"{kind}({args[0]})"] = _articulation(sim, kind, args[0])
            regions[args[0]] = _place(sim, args[0])
        else:
            raise UserInputError(
                f"goal predicate {list(predicate)} is not one of on/in (2 args), open/close/turnon/turnoff"
            )
    return {
        "version": GEOMETRY_VERSION,
        "goal": [list(p) for p in goal],
        "robot_base": [float(v) for v in sim.robot_base_position()],
        "table_height": float(sim.table_height),
        "regions": regions,
        "articulations": articulations,
    }
