"""Scripted experts that solve LIBERO tasks from the simulator state, with controllable execution quality."""

from base_suites.experts.expert import (
    EXPERT_VERSION,
    KNOBS,
    QUALITY_PRESETS,
    ScriptedExpert,
    draw_knobs,
    knob_rates,
    parse_quality,
    plan_skills,
)

__all__ = [
    "EXPERT_VERSION",
    "KNOBS",
    "QUALITY_PRESETS",
    "ScriptedExpert",
    "draw_knobs",
    "knob_rates",
    "parse_quality",
    "plan_skills",
]
