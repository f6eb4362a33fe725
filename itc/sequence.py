"""Task Sequence Integrity: sub-goals in a valid order, none undone, nothing else disturbed.

A sub-goal that already holds when the episode starts is a precondition, not an achievement: it counts
as satisfied for the order, and the robot may undo it (a closed drawer it must open first). Sub-goals
reached during the episode must respect the spec's precedence pairs and must not be undone (false for
`undo_grace_steps` steps in a row, since contact-based predicates flicker while objects settle).
Objects the task does not name must stay within `distractor_move` / `distractor_tilt` of their pose at
reset (or, for one still settling then, where it first came to rest), and fixtures it does not name
(drawers, doors, knobs) within `fixture_slide` / `fixture_hinge`. An object standing where a placement
still to be made will put its object (within `place_xy_tolerance` plus that object's reach of the
target's centre; libero_goal/5: the cream cheese stands where the plate must go) cannot stay put if
the task is to succeed: it may be moved, not tipped over.
Each disturbance is reported once, at the step it happens.
"""

from __future__ import annotations

import math

import numpy as np

from itc.base import Constraint, cm, deg
from itc.context import RestTracker, StepContext, angle_between, up_axis
from itc.spec import format_predicate

INITIAL, OPEN, REACHED = "initial", "open", "reached"


class SequenceIntegrity(Constraint):
    name = "sequence"

    def reset(self, ctx: StepContext) -> None:
        goals = self.spec.subgoals
        self._status = [INITIAL if ctx.predicate(g) else OPEN for g in goals]
        self._false_run = [0] * len(goals)
        distractors = tuple(n for n in self.spec.distractors if n in ctx.sim.objects)
        self._rest = RestTracker(ctx, distractors, self.params.rest_speed, self.params.rest_steps)
        self._anchors: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._in_the_way: set[str] = set()
        self._anchor(ctx)
        self._disturbed: set[str] = set()
        limits = {"slide": self.params.fixture_slide, "hinge": self.params.fixture_hinge}
        self._fixtures = {
            name: (ctx.sim.articulation(name), np.array([limits.get(ctx.sim.joint_type(j), math.inf) for j in joints]))
            for name, joints in ctx.sim.articulated.items()
            if name in self.spec.idle_fixtures
        }
        self._moved_fixtures: set[str] = set()

    def _anchor(self, ctx: StepContext) -> None:
        """Remember each distractor's pose once it has come to rest (it may still be settling at reset)."""
        for name in self._rest.settled - self._anchors.keys():
            axis = up_axis(ctx.rotation(name))
            self._anchors[name] = (ctx.position(name).copy(), axis, ctx.rotation(name) @ axis)
            pending = [p for p in self.spec.placements if self._status[p.subgoal] != INITIAL]
            if any(self._in_footprint(ctx, name, p) for p in pending):
                self._in_the_way.add(name)

    def _in_footprint(self, ctx: StepContext, name: str, placement) -> bool:
        """Whether `name` stands where `placement` will put its object: within the centre tolerance plus
        the object's reach (its farthest geometry from its centre, in xy) of the target's centre."""
        obj_xy = ctx.position(placement.obj)[:2]
        reach = float(np.max(np.linalg.norm(ctx.sim.geom_points(placement.obj)[:, :2] - obj_xy, axis=1)))
        centre = ctx.region(placement.target).centre if placement.target_is_region else ctx.position(placement.target)
        return float(np.linalg.norm(ctx.position(name)[:2] - centre[:2])) <= self.params.place_xy_tolerance + reach

    def check(self, ctx: StepContext) -> list[str]:
        self._rest.update(ctx)
        self._anchor(ctx)
        return self._subgoals(ctx) + self._distractors(ctx) + self._idle_fixtures(ctx)

    def _subgoals(self, ctx: StepContext) -> list[str]:
        reasons = []
        goals = self.spec.subgoals
        for i, goal in enumerate(goals):
            now = ctx.predicate(goal)
            status = self._status[i]
            if status == OPEN and now:
                self._status[i], self._false_run[i] = REACHED, 0
                missing = [j for j, k in self.spec.order if k == i and self._status[j] == OPEN]
                if missing:
                    before = ", ".join(format_predicate(goals[j]) for j in missing)
                    reasons.append(f"reached {format_predicate(goal)} before {before}")
            elif status == REACHED:
                self._false_run[i] = 0 if now else self._false_run[i] + 1
                if self._false_run[i] >= self.params.undo_grace_steps:
                    self._status[i] = OPEN
                    reasons.append(f"undid {format_predicate(goal)} (false for {self._false_run[i]} steps)")
            elif status == INITIAL and not now:
                self._status[i] = OPEN
        return reasons

    def _distractors(self, ctx: StepContext) -> list[str]:
        reasons = []
        p = self.params
        for name, (start, axis, start_up) in self._anchors.items():
            moved = float(np.linalg.norm(ctx.position(name) - start))
            turned = angle_between(ctx.rotation(name) @ axis, start_up)
            if (moved > p.distractor_move and name not in self._in_the_way) or turned > p.distractor_tilt:
                if name not in self._disturbed:
                    self._disturbed.add(name)
                    reasons.append(
                        f"disturbed {name}: moved {cm(moved)}, turned {deg(turned)} "
                        f"(limits {cm(p.distractor_move)}, {deg(p.distractor_tilt)})"
                    )
            else:
                self._disturbed.discard(name)
        return reasons

    def _idle_fixtures(self, ctx: StepContext) -> list[str]:
        reasons = []
        for name, (start, limits) in self._fixtures.items():
            delta = np.abs(ctx.sim.articulation(name) - start)
            if np.any(delta > limits):
                if name not in self._moved_fixtures:
                    self._moved_fixtures.add(name)
                    reasons.append(
                        f"moved {name}, which the task does not name (joint change {float(delta.max()):.3f})"
                    )
            else:
                self._moved_fixtures.discard(name)
        return reasons
