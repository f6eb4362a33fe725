"""The intervention method: `JITI(policy, critic)` wraps a base policy and, at critical moments, executes
the critic's choice among the policy's own candidates; `gate` chooses per task, from validation runs,
whether JITI runs at all. Names resolve on first use."""

from __future__ import annotations

from base_suites.runtime.lazy import lazy_getattr

_LAZY = {
    "JITI": "elegant.intervention.jiti",
    "Decision": "elegant.intervention.jiti",
    "task_gate": "elegant.intervention.gate",
    "write_gate": "elegant.intervention.gate",
    "read_gate": "elegant.intervention.gate",
}

__all__ = sorted(_LAZY)

__getattr__ = lazy_getattr(__name__, globals(), _LAZY)
