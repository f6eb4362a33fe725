"""Scripted experts built from a task's BDDL goal and the simulator state, with quality knobs.

The goal's predicates become an ordered list of skills (pick-and-place for On/In, articulated skills
for Open/Close/TurnOn/TurnOff); knobs drawn per episode make the execution sloppy in controlled,
recorded ways while mostly still succeeding, which is what elegance labels need.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from typing import Any

import numpy as np

from base_suites.env import LiberoEnv
from base_suites.experts import articulated, skills
from base_suites.experts.control import OPEN
from base_suites.experts.geometry import handle_pinch
from base_suites.experts.skills import SkillContext
from base_suites.runtime.errors import UserInputError, unknown_choice

EXPERT_VERSION = "scripted-11"
KNOBS = ("collide", "drop", "misplace", "tilt", "wrong_order", "jerky", "regrasp")
# "mixed": every knob possible, most episodes still clean in all but one or two respects.
MIXED_RATES = {
    "collide": 0.2,
    "drop": 0.2,
    "misplace": 0.15,
    "tilt": 0.2,
    "wrong_order": 0.15,
    "jerky": 0.15,
    "regrasp": 0.15,
}
QUALITY_PRESETS = {"clean": {k: 0.0 for k in KNOBS}, "mixed": MIXED_RATES}


def knob_rates(quality: str | Mapping[str, float]) -> dict[str, float]:
    """Resolve a quality preset name or a knob -> probability mapping (validated)."""
    if isinstance(quality, str):
        if quality not in QUALITY_PRESETS:
            raise unknown_choice("quality", quality, list(QUALITY_PRESETS) + ["knob=prob,..."])
        return dict(QUALITY_PRESETS[quality])
    rates = {k: 0.0 for k in KNOBS}
    for knob, p in quality.items():
        if knob not in KNOBS:
            raise unknown_choice("quality knob", knob, KNOBS)
        if not 0.0 <= float(p) <= 1.0:
            raise UserInputError(f"quality knob {knob!r}: probability {p} is outside [0, 1]")
        rates[knob] = float(p)
    return rates


def parse_quality(text: str) -> str | dict[str, float]:
    """CLI form: a preset name, or `knob=prob,knob=prob`."""
    if "=" not in text:
        return text
    out = {}
    for item in text.split(","):
        knob, _, prob = item.partition("=")
        try:
            out[knob.strip()] = float(prob)
        except ValueError:
            raise UserInputError(f"quality item {item!r}: expected knob=probability, e.g. drop=0.3") from None
    return out


def draw_knobs(rates: Mapping[str, float], seed: int, episode: int) -> tuple[dict[str, bool], np.random.Generator]:
    """The knobs of one episode, independent draws from (seed, episode); also returns the episode RNG."""
    rng = np.random.default_rng([seed, episode])
    return {k: bool(rng.random() < p) for k, p in rates.items()}, rng


Skill = Callable[[SkillContext], skills.Actions]


def plan_skills(goal: tuple[tuple[str, ...], ...], view) -> list[tuple[tuple[str, ...], Skill]]:
    """Order the goal's predicates into (predicate, skill) steps: switch on first, open containers
    before filling them, close containers after filling them. Opening a container for an `in` goal is
    a step of its own, keyed by the predicate it makes true; a drawer that starts partly open is pulled
    out to its end stop first (step ("pull_out", drawer)). An object the opened drawer would hang over
    is picked from under it afterwards if some grasp still reaches it (a bowl's rim sticking out: two
    fewer carries, ~100 steps, in a 300-step horizon), else first moved clear (step ("clear", object,
    drawer))."""
    steps: list[tuple[int, tuple[str, ...], Skill]] = []
    opened_for = set()
    targets = [p[2] for p in goal if p[0] in ("on", "in")]
    for pred in goal:
        kind, *args = pred
        if kind in ("on", "in"):
            obj, target = args
            container = articulated.container_of(view, target)
            if kind == "in" and container is not None and target not in opened_for:
                if not articulated.is_open(view, target):
                    if articulated.under_opened(view, target, obj):
                        steps.append(
                            (1, ("clear", obj, target), lambda c, o=obj, t=target: _clear_drawer_path(c, o, t))
                        )
                    steps.append((1, ("open", target), lambda c, t=target: articulated.open_(c, t)))
                elif articulated.pulled_short(view, target) > articulated.FULLY_OUT:
                    steps.append((1, ("pull_out", target), lambda c, t=target: articulated.pull_out(c, t)))
                opened_for.add(target)
            shared = targets.count(target) > 1
            steps.append((2, tuple(pred), lambda c, o=obj, t=target, s=shared: _pick_place(c, o, t, s)))
        elif kind == "open":
            steps.append((1, tuple(pred), lambda c, t=args[0]: articulated.open_(c, t)))
        elif kind == "close":
            steps.append((3, tuple(pred), lambda c, t=args[0]: articulated.close(c, t)))
        elif kind in ("turnon", "turnoff"):
            steps.append((0, tuple(pred), lambda c, t=args[0], k=kind: articulated.turn(c, t, on=k == "turnon")))
        else:
            raise UserInputError(f"goal predicate {kind!r} has no expert skill")
    steps.sort(key=lambda s: s[0])
    return [(pred, fn) for _, pred, fn in steps]


def _clear_drawer_path(ctx: SkillContext, obj: str, drawer: str) -> skills.Actions:
    """Move `obj` out from under where `drawer` will stand once opened, so it can be picked afterwards:
    lifted and carried just off the table (`skills.LOW_CARRY`), straight out from the cabinet, the move
    takes ~25 steps fewer than a carry over the cabinet's drawers (300-step horizon)."""
    ok = yield from skills.pick(ctx, obj, lift=skills.LOW_CARRY)
    if not ok:
        return False
    return (yield from skills.place(ctx, obj, articulated.clear_spot(ctx.view, drawer, obj), low=True))


def _pick_place(ctx: SkillContext, obj: str, target: str, shared: bool = False) -> skills.Actions:
    if not skills.can_grasp(ctx.view, obj):
        return (yield from skills.push(ctx, obj, target))
    door = articulated.doorway(ctx.view, target)
    if door is not None:
        ok = yield from skills.pick(ctx, obj, grasp_with=handle_pinch)
        return ok and (yield from skills.insert(ctx, obj, target, *door))
    ok = yield from skills.pick(ctx, obj, destination=skills.target_xy(ctx.view, target))
    if not ok:
        return False
    return (yield from skills.place(ctx, obj, target, shared=shared))


class ScriptedExpert:
    """A privileged policy for one `LiberoEnv`: call `reset()` after `env.reset()`, then `expert(obs)`."""

    def __init__(self, env: LiberoEnv, quality: str | Mapping[str, float] = "clean", seed: int = 0) -> None:
        self.env = env
        self.rates = knob_rates(quality)
        self.seed = int(seed)
        self._episode = 0
        self.knobs: dict[str, bool] = {}
        self.events: list[str] = []
        self._actions: Iterator[np.ndarray] | None = None

    def reset(self, metadata: Mapping[str, Any] | None = None, *, episode: int | None = None) -> None:
        """Start an episode (after `env.reset()`). Knobs are drawn from (seed, episode), so a resumed
        collection that passes the episode number reproduces the same episodes."""
        if episode is not None:
            self._episode = int(episode)
        self.knobs, rng = draw_knobs(self.rates, self.seed, self._episode)
        self._episode += 1
        self._rng = rng
        self._ctx = SkillContext(self.env.sim, rng, {k for k, on in self.knobs.items() if on})
        self.events = self._ctx.events
        self._actions = self._run()

    def _run(self) -> Iterator[np.ndarray]:
        ctx = self._ctx
        plan = plan_skills(self.env.task.goal, self.env.sim)
        if "collide" in ctx.knobs:
            victim = self._distractor()
            if victim is not None:
                yield from skills.knock(ctx, victim)
        if "wrong_order" in ctx.knobs:
            plan = self._out_of_order(plan)
        for _, skill in plan:
            yield from skill(ctx)
        while True:
            yield np.array([0, 0, 0, 0, 0, 0, OPEN])

    def _out_of_order(self, plan: list) -> list:
        """The `wrong_order` knob. LIBERO ends an episode at success, so undoing the final goal is never
        seen: with several sub-goals, the first one reached is undone and redone; with one, the expert
        first moves an object the task does not name."""
        goal = {tuple(p) for p in self.env.task.goal}
        first = next((i for i, (pred, _) in enumerate(plan) if pred in goal), None)
        if len(goal) > 1 and first is not None:
            pred = plan[first][0]
            self._ctx.events.append(f"wrong_order:undo:{pred[0]}")
            return plan[: first + 1] + [(("undo",), lambda c, p=pred: self._undo(c, p))] + plan[first:]
        victim = self._distractor()
        if victim is None:
            return plan
        self._ctx.events.append(f"wrong_order:first:{victim}")
        return [(("relocate", victim), lambda c, v=victim: self._relocate(c, v))] + plan

    def _relocate(self, ctx: SkillContext, obj: str, distance: tuple[float, float] = (0.05, 0.08)) -> skills.Actions:
        """Pick an object up and set it down `distance` metres away, in a random direction."""
        ok = yield from skills.pick(ctx, obj)
        if not ok:
            return False
        angle = ctx.rng.uniform(0, 2 * np.pi)
        spot = ctx.view.position(obj)[:2] + ctx.rng.uniform(*distance) * np.array([np.cos(angle), np.sin(angle)])
        return (yield from skills.place(ctx, obj, spot))

    def _undo(self, ctx: SkillContext, pred: tuple[str, ...]) -> skills.Actions:
        """Reverse one reached sub-goal: take the object back out, or re-close / re-open / switch back."""
        kind, *args = pred
        if kind in ("on", "in"):
            return (yield from self._relocate(ctx, args[0], distance=(0.14, 0.16)))
        if kind == "open":
            return (yield from articulated.close(ctx, args[0]))
        if kind == "close":
            return (yield from articulated.open_(ctx, args[0]))
        return (yield from articulated.turn(ctx, args[0], on=kind != "turnon"))

    def _distractor(self) -> str | None:
        named = {a for p in self.env.task.goal for a in p[1:]}
        view = self.env.sim
        candidates = [o for o in view.objects if o not in named and skills.can_grasp(view, o)]
        if not candidates:
            return None
        eef = view.eef_position()
        return min(candidates, key=lambda o: np.linalg.norm(view.position(o)[:2] - eef[:2]))

    def __call__(self, obs: Mapping[str, Any] | None = None) -> np.ndarray:
        if self._actions is None:
            self.reset()
        action = next(self._actions)
        if self.knobs.get("jerky"):
            noise = self._rng.normal(0, 0.35, size=6)
            if self._rng.random() < 0.1:
                noise += self._rng.choice([-1.0, 1.0], size=6)
            action = action.copy()
            action[:6] += noise
        return np.clip(action, -1.0, 1.0)
