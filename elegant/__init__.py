"""libero-elegant's top level: JITI, policies, evaluation, metrics, reports and the quickstart.

`from elegant import JITI; policy = JITI(base_policy, critic)` is the main entry point. Names are
resolved on first use (PEP 562) so that the CLI (`elegant --help`) does not pay for numpy, torch or the
simulator.
"""

from __future__ import annotations

from base_suites.runtime.lazy import lazy_getattr

_LAZY = {
    "JITI": "elegant.intervention.jiti",
    "Decision": "elegant.intervention.jiti",
    "Policy": "elegant.policies",
    "as_policy": "elegant.policies",
    "CallablePolicy": "elegant.policies",
    "LeRobotPolicy": "elegant.policies",
    "TorchRLPolicy": "elegant.policies",
    "BCPolicy": "elegant.policies",
    "load_policy": "elegant.policies",
    "train_policy": "elegant.policies",
    "evaluate": "elegant.evaluation.runner",
    "episode_start": "elegant.evaluation.runner",
    "task_gate": "elegant.intervention.gate",
    "write_gate": "elegant.intervention.gate",
    "collect_rollouts": "elegant.evaluation.rollouts",
    "summarize": "elegant.evaluation.metrics",
    "lifelong_metrics": "elegant.evaluation.metrics",
    "robustness_metrics": "elegant.evaluation.metrics",
    "paired_comparison": "elegant.evaluation.metrics",
    "rate_interval": "elegant.evaluation.metrics",
    "success_with_violation": "elegant.evaluation.metrics",
    "run_lifelong": "elegant.evaluation.lifelong",
    "run_lifelong_seeds": "elegant.evaluation.lifelong_table",
    "lifelong_table": "elegant.evaluation.lifelong_table",
    "run_robustness": "elegant.evaluation.robustness",
    "compare_runs": "elegant.reporting.report",
    "write_run_report": "elegant.reporting.report",
    "quickstart": "elegant.pipeline",
    "run_chain": "elegant.pipeline",
    "ChainConfig": "elegant.chain_config",
    "load_recipe": "elegant.chain_config",
}

__all__ = sorted(_LAZY)


__getattr__ = lazy_getattr(__name__, globals(), _LAZY)
