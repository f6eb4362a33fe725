"""Pose Alignment: upright objects stay upright, carried objects stay level, grasps approach squarely.

An object is watched once it is seen standing still: at rest for `rest_steps` steps, not held, one of
its body axes within `upright_arm` of vertical (that axis is its "up"; objects still settling after
reset, like a bowl sliding off a ramekin, are not judged until they stand). From then on:
- carrying a watched object leaning more than `upright_tolerance` violates alignment at every such
  step; watched are the spec's `upright` objects and everything the task moves (a box carried at 50
  degrees is as sloppy as a tilted mug);
- an `upright` object tipping over when nobody holds it (knocked, dropped, set down askew) violates it
  once, when it happens.
At each grasp the gripper's approach axis must lie within `approach_tolerance` of an object axis: for an
upright object along or across its up axis (it is round about that axis), for others any of the three
body axes (boxes are grasped square to a face).
"""

from __future__ import annotations

import math

import numpy as np

from itc.base import Constraint, deg
from itc.context import RestTracker, StepContext, angle_between, up_axis

_AXES = np.eye(3)


def _off_line(a: float) -> float:
    """Angle to a line rather than a direction: 170 deg from an axis is 10 deg off its line."""
    return min(a, math.pi - a)


class Alignment(Constraint):
    name = "alignment"

    def reset(self, ctx: StepContext) -> None:
        objects = ctx.sim.objects
        self._upright = frozenset(o for o in self.spec.upright if o in objects)
        watch = tuple(dict.fromkeys(o for o in self.spec.upright + self.spec.manipulated if o in objects))
        self._rest = RestTracker(ctx, watch, self.params.rest_speed, self.params.rest_steps)
        self._axis: dict[str, np.ndarray] = {}
        self._tipped: set[str] = set()
        self._arm(ctx)
        self._prev_held = ctx.held

    def _arm(self, ctx: StepContext) -> None:
        for name in self._rest.names:
            if name in self._axis or ctx.held == name or not self._rest.at_rest(name):
                continue
            axis = up_axis(ctx.rotation(name))
            if ctx.tilt_of(name, axis) <= self.params.upright_arm:
                self._axis[name] = axis

    def check(self, ctx: StepContext) -> list[str]:
        self._rest.update(ctx)
        self._arm(ctx)
        reasons = []
        limit = self.params.upright_tolerance
        for name, axis in self._axis.items():
            tilt = ctx.tilt_of(name, axis)
            if tilt <= limit:
                self._tipped.discard(name)
                continue
            if ctx.held == name:
                reasons.append(f"carrying {name} tilted {deg(tilt)} (limit {deg(limit)})")
            elif name in self._upright and name not in self._tipped:
                reasons.append(f"{name} tipped over to {deg(tilt)} (limit {deg(limit)})")
            self._tipped.add(name)
        if ctx.held is not None and ctx.held != self._prev_held:
            reasons += self._approach(ctx, ctx.held)
        self._prev_held = ctx.held
        return reasons

    def _approach(self, ctx: StepContext, name: str) -> list[str]:
        approach = ctx.eef_rotation[:, 2]
        rotation = ctx.rotation(name)
        limit = self.params.approach_tolerance
        if name in self._upright and name in self._axis:
            off_axis = _off_line(angle_between(approach, rotation @ self._axis[name]))
            off = min(off_axis, abs(math.pi / 2 - off_axis))
        else:
            off = min(_off_line(angle_between(approach, rotation @ axis)) for axis in _AXES)
        if off <= limit:
            return []
        return [f"grasped {name} approaching {deg(off)} off its axes (limit {deg(limit)})"]
