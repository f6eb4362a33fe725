"""Mode "consensus": at every decision, the candidate nearest the mean of the policy's candidates. A
control that needs no critic and no density from the policy: the consensus of its own draws."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from elegant.intervention.modes import CANDIDATE_SETTINGS, JITIMode, register_mode
from elegant.intervention.selectors import Choice, eligible_candidates
from elegant.intervention.triggers import Always


class NearestMean:
    """The eligible candidate nearest the eligible candidates' mean plan (by `plan_distance`'s measure: the
    RMS over the chunk of the per-step L2 distance): the consensus of the policy's own draws, which removes
    their noise without a critic."""

    def __init__(self, trust_radius: float | None) -> None:
        self.trust_radius = trust_radius

    def select(self, choice: Choice) -> int:
        eligible = eligible_candidates(choice.distance, self.trust_radius)
        mean = choice.plans[eligible].mean(axis=0)
        spread = np.sqrt(np.mean(np.sum((choice.plans - mean) ** 2, axis=-1), axis=-1))
        return int(np.argmin(np.where(eligible, spread, np.inf)))


def _describe(record: Mapping[str, Any], candidates: str) -> str:
    return f"consensus control: the candidate nearest the candidates' mean, at every decision; {candidates}"


register_mode(
    JITIMode(
        name="consensus",
        help="the candidate nearest the candidates' mean at every decision (no critic)",
        settings=CANDIDATE_SETTINGS,
        trigger=lambda config, steps: Always(),
        selector=lambda config: NearestMean(config.trust_radius),
        describe=_describe,
        needs_critic=False,
    )
)
