"""libero-elegant's top level: JITI, policies, evaluation, metrics, reports and the quickstart.

`from elegant import JITI; policy = JITI(base_policy, critic)` is the main entry point. Names are
resolved on first use (PEP 562) so that the CLI (`elegant --help`) does not pay for numpy, torch or the
simulator.
"""
from __future__ import annotations

import importlib
from typing import Any

_LAZY = {
    "JITI": "elegant.jiti",
    "Decision": "elegant.jiti",
    "Policy": "elegant.policies",
    "as_policy": "elegant.policies",
    "CallablePolicy": "elegant.policies",
    "LeRobotPolicy": "elegant.policies",
    "TorchRLPolicy": "elegant.policies",
    "BCPolicy": "elegant.policies",
    "load_policy": "elegant.policies",
    "train_policy": "elegant.policies",
    "evaluate": "elegant.evaluation",
    "episode_start": "elegant.evaluation",
    "summarize": "elegant.metrics",
    "lifelong_metrics": "elegant.metrics",
    "robustness_metrics": "elegant.metrics",
    "compare_runs": "elegant.report",
    "write_run_report": "elegant.report",
    "quickstart": "elegant.quickstart",
    "QuickstartConfig": "elegant.quickstart",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
