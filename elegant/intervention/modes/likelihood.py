"""Mode "likelihood": at every decision, the candidate the base policy itself finds most probable. A
control that needs no critic: what re-ranking the policy's own draws gains without any judge of where
they lead (with a drawn act it removes the draw's noise)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from elegant.intervention.modes import CANDIDATE_SETTINGS, JITIMode, register_mode
from elegant.intervention.selectors import Choice, eligible_candidates
from elegant.intervention.triggers import Always


class MostProbable:
    """The eligible candidate the base policy itself finds most probable (its highest log-density; the
    first of equals, so the base plan wins a tie): a choice that needs no critic."""

    def __init__(self, trust_radius: float | None) -> None:
        self.trust_radius = trust_radius

    def select(self, choice: Choice) -> int:
        log_prob = np.asarray(choice.log_prob(), dtype=np.float64).reshape(-1)
        if log_prob.shape != choice.distance.shape:
            raise ValueError(f"the policy's log_prob returned {log_prob.shape} for {len(choice.distance)} plans")
        eligible = eligible_candidates(choice.distance, self.trust_radius)
        return int(np.argmax(np.where(eligible, log_prob, -np.inf)))


def _describe(record: Mapping[str, Any], candidates: str) -> str:
    return f"likelihood control: the candidate the policy finds most probable, at every decision; {candidates}"


register_mode(
    JITIMode(
        name="likelihood",
        help="the policy's most probable candidate at every decision (no critic)",
        settings=CANDIDATE_SETTINGS,
        trigger=lambda config, steps: Always(),
        selector=lambda config: MostProbable(config.trust_radius),
        describe=_describe,
        needs_critic=False,
        policy_needs=("log_prob_plans",),
    )
)
