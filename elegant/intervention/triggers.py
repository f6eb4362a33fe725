"""When JITI draws and re-ranks candidates: the triggers, by name (docs/design.md, JITI).

A trigger sees one decision (`Moment`): the base plan's score q, the window's mean m and threshold tau
(None while the window fills), the env step, the episode's overrides so far and the run's seeded
generator. Each mode (`elegant.intervention.modes`) builds its trigger from these; mode "jiti"'s steered
warm-up and override budget wrap its critical-moment trigger (`SteeredWarmup`, `OverrideBudget`).
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass(slots=True)
class Moment:
    """One decision as a trigger sees it (built at every decision JITI does not re-rank outright: slots, no
    frozen-instance checks, to keep a decision cheap)."""

    step: int
    q: float | None
    mean: float | None
    tau: float | None
    overrides: int
    rng: np.random.Generator


class Trigger(Protocol):
    """`fires(moment)`: whether to draw and re-rank candidates at this decision. `every_decision`: it
    fires at every one, so all candidates can be drawn and scored in one batch before it is asked."""

    every_decision: bool

    def fires(self, moment: Moment) -> bool: ...


class Deviation:
    """A critical moment: the score strays from the window's mean by more than tau, either way."""

    every_decision = False

    def fires(self, moment: Moment) -> bool:
        return moment.mean is not None and abs(moment.q - moment.mean) > moment.tau


class Drop:
    """A critical moment: the score falls more than tau below the window's mean. A critic trained on the
    outcome climbs as the task progresses and the lagging mean would make the whole climb critical."""

    every_decision = False

    def fires(self, moment: Moment) -> bool:
        return moment.mean is not None and moment.mean - moment.q > moment.tau


class Never:
    """Never fires: the base policy runs as it is (mode "base", or mode "jiti" steering its warm-up only)."""

    every_decision = False

    def fires(self, moment: Moment) -> bool:
        return False


class Always:
    """Fires at every decision: the V-GPS baseline, re-ranking all the time."""

    every_decision = True

    def fires(self, moment: Moment) -> bool:
        return True


class RandomRate:
    """Fires at a seeded random `rate` of decisions: the control for the critic's timing."""

    every_decision = False

    def __init__(self, rate: float) -> None:
        self.rate = float(rate)

    def fires(self, moment: Moment) -> bool:
        return moment.rng.random() < self.rate


class AtSteps:
    """Fires exactly at the decisions taken at `steps`: branch rollouts that differ in one decision."""

    every_decision = False

    def __init__(self, steps: Collection[int]) -> None:
        self.steps = frozenset(int(t) for t in steps)

    def fires(self, moment: Moment) -> bool:
        return moment.step in self.steps


class SteeredWarmup:
    """Fires while the window fills (no mean yet) as well as whenever `inner` does: the start of an episode,
    where the policy commits to its approach and grasp, is a critical moment no fluctuation reveals."""

    every_decision = False

    def __init__(self, inner: Trigger) -> None:
        self.inner = inner

    def fires(self, moment: Moment) -> bool:
        return self.inner.fires(moment) or moment.mean is None


class OverrideBudget:
    """`inner`, until the episode's overrides reach `limit`: then never again."""

    every_decision = False

    def __init__(self, inner: Trigger, limit: int) -> None:
        self.inner, self.limit = inner, int(limit)

    def fires(self, moment: Moment) -> bool:
        return moment.overrides < self.limit and self.inner.fires(moment)


CRITICAL_MOMENTS: dict[str, type[Trigger]] = {"deviation": Deviation, "drop": Drop, "none": Never}
