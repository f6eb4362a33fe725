"""Per-step ITC evaluation of one env, and the episode's verdict.

Usage::

    monitor = ITCMonitor(env)             # spec derived from the env's task
    obs, info = env.reset(); monitor.reset()
    obs, r, terminated, truncated, info = env.step(action)
    result = monitor.step(action)         # .kept, .reasons, .reward
    verdict = monitor.verdict(info["success"])   # .elegant, .violated, .segments, .steps

Step t judges the transition (s_t, a_t, s_t+1) from the simulator state after the step. The elegance
reward is 1 when all four criteria are kept; an episode is an elegant success when it succeeds and no
window of `segment_length` frames violates any criterion.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from base_suites.rollout import StepObserver
from itc.context import StepContext
from itc.params import ITCParams
from itc.registry import CRITERIA, make_constraints
from itc.segments import segment_labels
from itc.spec import ConstraintSpec, derive_spec

MAX_LISTED_EVENTS = 20  # a long press is one event per step; episode logs list the first ones


@dataclass(frozen=True)
class StepResult:
    """Whether one step kept each criterion, and why not where it did not."""

    step: int
    kept: dict[str, bool]
    reasons: dict[str, list[str]]

    @property
    def reward(self) -> float:
        """The elegance reward: 1.0 iff every criterion is kept."""
        return float(all(self.kept.values()))

    def to_info(self) -> dict[str, Any]:
        return {
            "step": self.step,
            "kept": dict(self.kept),
            "reasons": {k: list(v) for k, v in self.reasons.items() if v},
        }


@dataclass(frozen=True)
class EpisodeVerdict:
    """Labels of one episode: per-step and per-window flags per criterion (True = kept)."""

    success: bool
    steps: Mapping[str, np.ndarray]
    segments: Mapping[str, np.ndarray]
    events: tuple[tuple[int, str, str], ...]
    """(step, criterion, reason) of every violation, in order."""
    segment_length: int

    @classmethod
    def from_steps(cls, success: bool, steps: Mapping[str, np.ndarray], events, segment_length: int) -> EpisodeVerdict:
        steps = {c: np.asarray(steps[c], dtype=bool) for c in CRITERIA}
        segments = {c: segment_labels(steps[c], segment_length) for c in CRITERIA}
        return cls(bool(success), steps, segments, tuple(events), int(segment_length))

    @property
    def violated(self) -> list[str]:
        return [c for c in CRITERIA if not self.segments[c].all()]

    @property
    def elegant(self) -> bool:
        return self.success and not self.violated

    @property
    def elegance_reward(self) -> np.ndarray:
        return np.logical_and.reduce([self.steps[c] for c in CRITERIA]).astype(np.float32)

    def to_dict(self) -> dict[str, Any]:
        return {
            "success": self.success,
            "elegant": self.elegant,
            "violated": self.violated,
            "segment_length": self.segment_length,
            "segments": {c: self.segments[c].tolist() for c in CRITERIA},
            "violation_steps": {c: np.flatnonzero(~self.steps[c]).tolist() for c in CRITERIA},
            "events": [list(e) for e in self.events[:MAX_LISTED_EVENTS]],
            "num_events": len(self.events),
        }


class ITCMonitor(StepObserver):
    """Evaluates the four ITCs on one env (a `LiberoEnv` or a wrapper around one), step by step; as a
    `StepObserver` it judges each step of `base_suites.rollout.run_episode`."""

    def __init__(self, env, spec: ConstraintSpec | None = None, params: ITCParams | None = None) -> None:
        base = getattr(env, "unwrapped", env)
        self.sim = base.sim
        self.spec = spec if spec is not None else derive_spec(base)
        self.params = self.spec.effective_params(params)
        self.constraints = make_constraints(self.spec, self.params)
        self._steps: dict[str, list[bool]] = {c: [] for c in CRITERIA}
        self._events: list[tuple[int, str, str]] = []
        self._started = False

    def reset(self) -> None:
        """Start an episode at the current state (call right after `env.reset`)."""
        ctx = StepContext(self.sim)
        for constraint in self.constraints:
            constraint.reset(ctx)
        self._steps = {c: [] for c in CRITERIA}
        self._events = []
        self._started = True

    @property
    def num_steps(self) -> int:
        return len(self._steps[CRITERIA[0]])

    def step(self, action: np.ndarray | None = None, goal_reached: bool = False) -> StepResult:
        """Judge the step just taken (call right after `env.step(action)`).

        The criteria read the resulting simulator state; `action` completes the (s, a, s') call shape
        that policies and replays use and is not needed by the current criteria. `goal_reached`: the
        episode's own record says LIBERO found the task goal holding after this step, so every goal
        predicate holds here whatever the simulator says now. A replay needs it: LIBERO judged the goal
        with the contacts MuJoCo found at the start of its last physics substep, while a jump to the
        recorded state finds contacts afresh, and an object that touched down at speed has by then
        bounced a fraction of a millimetre off its target (a bowl set on the cabinet: 18% of goal/4 demos).
        """
        if not self._started:
            raise RuntimeError("ITCMonitor.step() before reset(): call monitor.reset() after env.reset()")
        t = self.num_steps
        ctx = StepContext(self.sim, {p: True for p in self.spec.subgoals} if goal_reached else None)
        reasons = {c.name: c.check(ctx) for c in self.constraints}
        for name, why in reasons.items():
            self._steps[name].append(not why)
            self._events.extend((t, name, r) for r in why)
        return StepResult(t, {name: not why for name, why in reasons.items()}, reasons)

    def after_step(self, env: Any, action: np.ndarray, obs: Any, reward: float, info: Mapping[str, Any]) -> bool:
        """`run_episode`'s hook: judge the step just taken."""
        self.step(action)
        return False

    def verdict(self, success: bool) -> EpisodeVerdict:
        """The labels of the episode so far."""
        return EpisodeVerdict.from_steps(success, self._steps, self._events, self.params.segment_length)
