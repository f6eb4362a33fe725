"""Mode "jiti": the critic re-ranks at critical moments, when the base plan's score strays from the window
of past scores; the steered warm-up re-ranks while the window fills, the override budget caps an
episode's overrides (both wrap the critical-moment trigger)."""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import Any

from base_suites.runtime.errors import UserInputError
from elegant.intervention.modes import CANDIDATE_SETTINGS, JITIMode, register_mode
from elegant.intervention.selectors import CriticArgmax
from elegant.intervention.triggers import CRITICAL_MOMENTS, OverrideBudget, SteeredWarmup, Trigger


def _trigger(config: Any, steps: Collection[int] | None) -> Trigger:
    trigger: Trigger = CRITICAL_MOMENTS[config.trigger]()
    if config.warmup == "steer":
        trigger = SteeredWarmup(trigger)
    if config.max_overrides is not None:
        trigger = OverrideBudget(trigger, config.max_overrides)
    return trigger


def _check(config: Any) -> None:
    if config.trigger == "none" and config.warmup != "steer":
        raise UserInputError("JITI trigger 'none' never intervenes unless the warm-up is steered (warmup='steer')")


def _describe(record: Mapping[str, Any], candidates: str) -> str:
    budget = record["max_overrides"]
    choice = f"min gain {record['min_gain']}, override budget {budget if budget is not None else 'none'}"
    trigger = (
        f"trigger {record['trigger']}, warm-up {record['warmup']}, "
        f"window {record['window']}, threshold {record['threshold']} ({record['threshold_mode']})"
    )
    return f"JITI: {trigger}; {candidates}; {choice}"


register_mode(
    JITIMode(
        name="jiti",
        help="re-rank at critical moments",
        settings=(
            "window",
            "threshold",
            "threshold_mode",
            "trigger",
            "warmup",
            *CANDIDATE_SETTINGS,
            "min_gain",
            "max_overrides",
        ),  # fmt: skip
        trigger=_trigger,
        selector=lambda config: CriticArgmax(config.trust_radius, config.min_gain),
        describe=_describe,
        needs_critic=True,
        uses_window=True,
        check=_check,
    )
)
