"""Mode "random": a random eligible candidate at a seeded rate of decisions, or at listed steps: the
control for the critic's choice and timing, and the exploration of recorded rollouts."""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import Any

from elegant.intervention.modes import CANDIDATE_SETTINGS, JITIMode, register_mode
from elegant.intervention.selectors import RandomEligible
from elegant.intervention.triggers import AtSteps, RandomRate, Trigger


def _trigger(config: Any, steps: Collection[int] | None) -> Trigger:
    return AtSteps(steps) if steps is not None else RandomRate(config.random_rate)


def _describe(record: Mapping[str, Any], candidates: str) -> str:
    return f"random control: a random candidate at {record['random_rate']} of decisions; {candidates}"


register_mode(
    JITIMode(
        name="random",
        help="a random candidate at --random-rate of decisions",
        settings=(*CANDIDATE_SETTINGS, "random_rate"),
        trigger=_trigger,
        selector=lambda config: RandomEligible(config.trust_radius),
        describe=_describe,
        needs_critic=False,
    )
)
