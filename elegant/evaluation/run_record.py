"""An evaluation run's record, RUN/config.json: its format and the migration of each older version
(`base_suites.runtime.records`). Every reader of a run's config (resume, report, gate) upgrades it here
first, so none of them fills in what an older run lacked.
"""

from __future__ import annotations

from typing import Any

from base_suites.runtime.records import NOT_RECORDED, RecordFormat, fill_missing
from elegant.intervention.config import mode_record


def _render_quality_of(record: dict[str, Any]) -> str | None:
    """Before the render quality was a setting, every image observation was rendered without shadows,
    reflections or multisampling ("fast"); a run without images records None."""
    return None if record.get("obs", "lowdim") == "lowdim" else "fast"


def _run_from_v1(record: dict[str, Any]) -> dict[str, Any]:
    """A version-1 run config.json as version 2. Version 1 records were written across the settings added
    since the first: before chunking (one action per decision), before mode "random" (so its rate did
    nothing), before a subset of init states, the minimum gain, the one-sided trigger, the override
    budget, the steered warm-up, the policy act, the render quality and the VLA image size; each gets the
    value those runs had. They also recorded every JITI setting, used by their mode or not: cut to the mode's."""
    record = fill_missing(
        record,
        {
            "render_quality": _render_quality_of,
            "vla_image_size": None,
            "init_states": None,
            "policy_act": "mode",
            "candidate_source": NOT_RECORDED,
            "device": "cpu",
            "jiti": {
                "chunk": 1,
                "random_rate": NOT_RECORDED,
                "min_gain": 0.0,
                "trigger": "deviation",
                "max_overrides": None,
                "warmup": "base",
            },
        },
    )
    if isinstance(record.get("jiti"), dict):
        record["jiti"] = mode_record(record["jiti"], record.get("mode"))
    return record


RUN_RECORD = RecordFormat("libero-elegant-run", 2, {1: _run_from_v1})


def read_run_config(record: Any, where: str) -> dict[str, Any]:
    """A run's config.json content as today's record (refused in one line if of another format)."""
    return RUN_RECORD.upgrade(record, where)
