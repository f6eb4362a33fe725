"""When JITI draws and re-ranks candidates: the triggers, by name (docs/design.md, JITI).

A trigger sees one decision (`Moment`): the base plan's score q, the window's mean m and threshold tau
(None while the window fills), the env step and the run's seeded generator. Modes are presets: "base"
never fires, "always" fires at every decision, "jiti" fires at its critical moments, "random" at a
random rate or at listed steps. Mode "jiti"'s steered warm-up and override budget wrap its trigger in
`JITI` itself, since they apply to no other mode.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from elegant.intervention.config import JITIConfig


@dataclass(slots=True)
class Moment:
    """One decision as a trigger sees it (built at every decision JITI does not re-rank outright: slots, no
    frozen-instance checks, to keep a decision cheap)."""

    step: int
    q: float | None
    mean: float | None
    tau: float | None
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


CRITICAL_MOMENTS = {"deviation": Deviation, "drop": Drop, "none": Never}


def make_trigger(config: JITIConfig, random_steps: Collection[int] | None = None) -> Trigger:
    """The trigger of `config.mode`; in mode "random", `random_steps` (if given) replaces the random rate."""
    if config.mode == "base":
        return Never()
    if config.mode == "always":
        return Always()
    if config.mode == "random":
        return AtSteps(random_steps) if random_steps is not None else RandomRate(config.random_rate)
    return CRITICAL_MOMENTS[config.trigger]()
