"""libero-elegant's top level: JITI, policies, evaluation, metrics, reports and the quickstart.

`from elegant import JITI; policy = JITI(base_policy, critic)` is the main entry point. Names are
resolved on first use (PEP 562) so that the CLI (`elegant --help`) does not pay for numpy, torch or the
simulator.
"""
from __future__ import annotations

from base_suites.lazy import lazy_getattr

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
    "task_gate": "elegant.gate",
    "write_gate": "elegant.gate",
    "intervention_headroom": "elegant.headroom",
    "rescore_headroom": "elegant.headroom",
    "collect_rollouts": "elegant.rollouts",
    "summarize": "elegant.metrics",
    "lifelong_metrics": "elegant.metrics",
    "robustness_metrics": "elegant.metrics",
    "paired_comparison": "elegant.metrics",
    "rate_interval": "elegant.metrics",
    "success_with_violation": "elegant.metrics",
    "run_lifelong": "elegant.lifelong",
    "compare_runs": "elegant.report",
    "write_run_report": "elegant.report",
    "quickstart": "elegant.pipeline",
    "run_chain": "elegant.pipeline",
    "ChainConfig": "elegant.pipeline",
}

__all__ = sorted(_LAZY)


__getattr__ = lazy_getattr(__name__, globals(), _LAZY)
