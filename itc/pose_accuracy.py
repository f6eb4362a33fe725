"""Target Pose Accuracy: a placed object ends near its target's centre and stays there.

A placement is judged once per attempt (an attempt starts when the robot grasps the object):
- when its on/in sub-goal becomes true during the episode (LIBERO ends a successful episode right there,
  so this is often the only chance), or
- when the object, released within `placement_radius` of its target, touching it, or beside a movable
  target (within `beside_margin` of a basket's outside), comes to rest (released near the target counts
  even if it then rolls or bounces farther away: that is the failure).
The object must then lie within `place_xy_tolerance` of the target's centre; where several goal objects
share one region (two items in a basket, two pots on a stove) they cannot all sit at its centre, so the
tolerance there grows per axis to the region's half size minus `region_edge_margin` (an ellipse test).
A placement judged good that later leaves the tolerance while nobody holds it (slid or bounced out, or
knocked away) is a violation at that step.
An object pushed or dragged into a goal region without being carried there (a plate slid over the
table) turns its sub-goal true as it crosses the region's edge, so at that instant it always sits at the
edge: it is judged like a release instead, once at rest. LIBERO ends a single-goal episode right there,
so it is then never judged, and its placement is the goal predicate itself (LIBERO's region test).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from itc.base import Constraint, cm
from itc.context import StepContext
from itc.spec import Placement


@dataclass
class _Attempt:
    carried: bool = False  # the robot grasped the object in this attempt (else it is pushed, if at all)
    released: bool = False
    release_xy: np.ndarray | None = None
    rest_steps: int = 0
    judged: bool = False
    placed: bool = False


class PoseAccuracy(Constraint):
    name = "pose_accuracy"

    def reset(self, ctx: StepContext) -> None:
        self._goal_held = [ctx.predicate(self.spec.subgoals[p.subgoal]) for p in self.spec.placements]
        self._attempts = [_Attempt() for _ in self.spec.placements]
        targets = [p.target for p in self.spec.placements]
        self._shared = {t for t in targets if targets.count(t) > 1}
        self._prev_held = ctx.held

    def check(self, ctx: StepContext) -> list[str]:
        reasons: list[str] = []
        for k, placement in enumerate(self.spec.placements):
            goal_now = ctx.predicate(self.spec.subgoals[placement.subgoal])
            reasons += self._follow(ctx, placement, k, goal_now)
            self._goal_held[k] = goal_now
        self._prev_held = ctx.held
        return reasons

    def _follow(self, ctx: StepContext, placement: Placement, k: int, goal_now: bool) -> list[str]:
        obj, p = placement.obj, self.params
        held = ctx.held == obj
        if held and self._prev_held != obj:
            self._attempts[k] = _Attempt(carried=True)
        attempt = self._attempts[k]
        if not held and self._prev_held == obj:
            attempt.released, attempt.rest_steps = True, 0
            attempt.release_xy = ctx.position(obj)[:2].copy()
        if goal_now and not self._goal_held[k] and not attempt.judged:
            if placement.target_is_region and not attempt.carried and not held:  # pushed in: judge at rest
                attempt.released, attempt.rest_steps, attempt.release_xy = True, 0, ctx.position(obj)[:2].copy()
                return []
            return self._judge(ctx, placement, attempt)
        if attempt.released and not held:
            attempt.rest_steps = attempt.rest_steps + 1 if ctx.speed(obj) < p.rest_speed else 0
            if attempt.rest_steps >= p.rest_steps:
                attempt.released = False
                if not attempt.judged and self._near(ctx, placement, attempt.release_xy):
                    return self._judge(ctx, placement, attempt)
                attempt.carried = False  # at rest elsewhere: whatever moves it next without a grasp pushes it
        if attempt.placed and not held and not attempt.released:
            ok, error = self._error(ctx, placement)
            if not ok:
                attempt.placed = False
                return [f"{obj} left its place on {placement.target}: now {error}"]
        return []

    def _judge(self, ctx: StepContext, placement: Placement, attempt: _Attempt) -> list[str]:
        ok, error = self._error(ctx, placement)
        attempt.judged, attempt.placed = True, ok
        return [] if ok else [f"{placement.obj} placed on {placement.target} {error}"]

    def _centre(self, ctx: StepContext, placement: Placement) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Target centre, its horizontal axes (2x2, one per column), and the xy tolerance along them."""
        p = self.params
        if not placement.target_is_region:
            return ctx.position(placement.target), np.eye(2), np.full(2, p.place_xy_tolerance)
        region = ctx.region(placement.target)
        axes, half = region.footprint()
        tol = np.full(2, p.place_xy_tolerance)
        if half is not None and placement.target in self._shared:
            tol = np.maximum(tol, half - p.region_edge_margin)
        return region.centre, axes, tol

    def _error(self, ctx: StepContext, placement: Placement) -> tuple[bool, str]:
        centre, axes, tol = self._centre(ctx, placement)
        local = axes.T @ (ctx.position(placement.obj) - centre)[:2]
        ok = float(np.sum((local / tol) ** 2)) <= 1.0
        distance = cm(float(np.linalg.norm(local)))
        return (
            ok,
            f"{distance} from its centre (offset {cm(local[0])}, {cm(local[1])}; allowed {cm(tol[0])} x {cm(tol[1])})",
        )

    def _near(self, ctx: StepContext, placement: Placement, release_xy: np.ndarray | None) -> bool:
        """Whether a release was a placement attempt at the target: it rests, or was let go, near it."""
        centre, _, _ = self._centre(ctx, placement)
        points = [ctx.position(placement.obj)[:2]] + ([release_xy] if release_xy is not None else [])
        close = min(float(np.linalg.norm(p - centre[:2])) for p in points) <= self.params.placement_radius
        return (
            close
            or (placement.target_entity is not None and placement.target_entity in ctx.touches(placement.obj))
            or self._beside(ctx, placement)
        )

    def _beside(self, ctx: StepContext, placement: Placement) -> bool:
        """Whether the object rests next to its movable target (xy bounding boxes within `beside_margin`).
        Fixtures are left out: clearing a bowl from a drawer's path sets it down beside the cabinet on purpose."""
        target = placement.target_entity
        if target is None or target not in ctx.sim.objects:
            return False
        held, other = ctx.sim.geom_points(placement.obj)[:, :2], ctx.sim.geom_points(target)[:, :2]
        gap = np.maximum(0.0, np.maximum(other.min(axis=0) - held.max(axis=0), held.min(axis=0) - other.max(axis=0)))
        return float(np.linalg.norm(gap)) <= self.params.beside_margin
