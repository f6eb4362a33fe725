"""Mode "always": the critic re-ranks every decision (the V-GPS baseline)."""

from __future__ import annotations

from elegant.intervention.modes import CANDIDATE_SETTINGS, JITIMode, register_mode
from elegant.intervention.selectors import CriticArgmax
from elegant.intervention.triggers import Always


def _describe(record, candidates: str) -> str:
    return f"always: the critic re-ranks every decision; {candidates}; min gain {record['min_gain']}"


register_mode(
    JITIMode(
        name="always",
        help="the critic re-ranks every decision",
        settings=(*CANDIDATE_SETTINGS, "min_gain"),
        trigger=lambda config, steps: Always(),
        selector=lambda config: CriticArgmax(config.trust_radius, config.min_gain),
        describe=_describe,
        needs_critic=True,
    )
)
