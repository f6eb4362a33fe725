"""Grasp and placement geometry from the simulator's collision shapes.

A general grasp chooser instead of per-task trajectories: for every candidate yaw it checks that the
object fits between the fingers (the Panda opens ~8 cm) or, for wide round objects (bowls, plates),
grasps the rim radially; it then keeps the candidate whose hand footprint (~21 cm along the closing
direction) stays clearest of the neighbours, since the hand hitting neighbours is the main failure.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from base_suites.experts.control import finger_axis
from base_suites.sim_view import SimView

MAX_WIDTH = 0.072  # widest object the fingers close around reliably
HAND_HALF_LENGTH = 0.105  # hand extent along the closing direction, each side of the centre
HAND_HALF_WIDTH = 0.035
YAWS = np.deg2rad(np.arange(-90, 90, 15))


@dataclass(frozen=True)
class Grasp:
    position: np.ndarray
    yaw: float
    clearance: float
    rim: bool


@dataclass(frozen=True)
class Shape:
    """Axis-aligned world extents of an entity's collision geoms."""

    low: np.ndarray
    high: np.ndarray

    @property
    def centre(self) -> np.ndarray:
        return (self.low + self.high) / 2

    @property
    def top(self) -> float:
        return float(self.high[2])

    @property
    def bottom(self) -> float:
        return float(self.low[2])

    @property
    def height(self) -> float:
        return float(self.high[2] - self.low[2])


def shape_of(view: SimView, entity: str) -> Shape:
    pts = view.geom_points(entity)
    return Shape(pts.min(axis=0), pts.max(axis=0))


def _extent(points: np.ndarray, direction: np.ndarray) -> float:
    proj = points[:, :2] @ direction[:2]
    return float(proj.max() - proj.min())


def _hand_clearance(centre: np.ndarray, yaw: float, z: float, obstacles: np.ndarray) -> float:
    """Smallest xy distance from obstacle points (above the fingertips) to the hand's footprint."""
    if len(obstacles) == 0:
        return 1.0
    relevant = obstacles[obstacles[:, 2] > z - 0.01]
    if len(relevant) == 0:
        return 1.0
    along = finger_axis(yaw)[:2]
    across = np.array([-along[1], along[0]])
    rel = relevant[:, :2] - centre[:2]
    a = np.abs(rel @ along) - HAND_HALF_LENGTH
    c = np.abs(rel @ across) - HAND_HALF_WIDTH
    outside = np.sqrt(np.clip(a, 0, None) ** 2 + np.clip(c, 0, None) ** 2)
    inside = np.minimum(np.maximum(a, c), 0)
    return float(np.min(np.where((a > 0) | (c > 0), outside, inside)))


def _obstacle_points(view: SimView, entity: str) -> np.ndarray:
    others = [view.geom_points(e) for e in view.objects + view.fixtures if e != entity]
    return np.concatenate(others) if others else np.zeros((0, 3))


def choose_grasp(view: SimView, entity: str, prefer_yaw: float = 0.0) -> Grasp:
    """The clearest feasible top-down grasp of an object (pinch across a narrow side, or a rim grasp)."""
    points = view.geom_points(entity)
    shape = Shape(points.min(axis=0), points.max(axis=0))
    obstacles = _obstacle_points(view, entity)
    centre = shape.centre
    pinches, rims = [], []
    for yaw in YAWS:
        axis = finger_axis(yaw)
        width = _extent(points, axis)
        if width <= MAX_WIDTH:
            z = max(shape.bottom + 0.012, shape.top - min(0.035, shape.height * 0.5))
            pinches.append(Grasp(np.array([centre[0], centre[1], z]), float(yaw), 0.0, rim=False))
        elif shape.height > 0.03:
            # Rim grasp of a wide round object: the fingers straddle the wall along the closing axis.
            radius = width / 2
            z = shape.top - 0.018
            rims += [
                Grasp(np.array([*(centre[:2] + s * (radius - 0.012) * axis[:2]), z]), float(yaw), 0.0, rim=True)
                for s in (-1.0, 1.0)
            ]

    base = view.robot_base_position()[:2]

    def score(cand: Grasp) -> tuple[float, Grasp]:
        clearance = _hand_clearance(cand.position, cand.yaw, cand.position[2], obstacles)
        # Clearance first (capped: beyond 4 cm it no longer matters), then little wrist rotation, then
        # rim points on the robot's side: the object then hangs away from the robot and every later
        # move of the hand stays further inside the arm's reach.
        reach = float(np.linalg.norm(cand.position[:2] - base)) if cand.rim else 0.0
        value = min(clearance, 0.04) * 10 - 0.02 * abs(cand.yaw - prefer_yaw) - 1.0 * reach
        return value, Grasp(cand.position, cand.yaw, clearance, cand.rim)

    scored = [score(c) for c in pinches]
    if not scored or max(v for v, _ in scored) <= 0.05:  # no pinch clear of the neighbours
        scored += [score(c) for c in rims]
    if not scored:
        raise RuntimeError(f"no top-down grasp fits {entity}")
    return max(scored, key=lambda vs: vs[0])[1]


def carry_height(view: SimView, held: str, goal_xy: np.ndarray, margin: float = 0.05, clearance: float = 0.06) -> float:
    """Height of the grip point that keeps the held object's bottom `margin` above everything in the
    corridor between where it is and where it goes (not above the whole scene: tall cabinets elsewhere
    would force needlessly high, slow carries)."""
    held_shape = shape_of(view, held)
    grip_to_bottom = view.eef_position()[2] - held_shape.bottom
    start = held_shape.centre[:2]
    corridor = 0.5 * float(np.max(held_shape.high[:2] - held_shape.low[:2])) + clearance
    seg = np.asarray(goal_xy, dtype=float)[:2] - start
    length = max(np.linalg.norm(seg), 1e-6)
    tops = [view.table_height]
    for entity in view.objects + view.fixtures:
        if entity == held:
            continue
        pts = view.geom_points(entity)
        rel = pts[:, :2] - start
        t = np.clip(rel @ seg / length**2, 0, 1)
        dist = np.linalg.norm(rel - t[:, None] * seg, axis=1)
        near = pts[dist < corridor]
        if len(near):
            tops.append(float(near[:, 2].max()))
    return max(tops) + margin + grip_to_bottom
