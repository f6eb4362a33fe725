"""What a person reads: a run's report (`write_run_report`: markdown and plots beside summary.json) and
the side-by-side comparison of runs (`compare_runs`), paired on their shared starts."""

from __future__ import annotations

from base_suites.runtime.lazy import lazy_getattr

_LAZY = {"compare_runs": "elegant.reporting.report", "write_run_report": "elegant.reporting.report"}

__all__ = sorted(_LAZY)

__getattr__ = lazy_getattr(__name__, globals(), _LAZY)
