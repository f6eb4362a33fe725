"""Running policies in the simulator: the evaluation runner (`evaluate`, with each episode's start fixed by
`episode_start`), recorded rollouts for critic data (`collect_rollouts`), LIBERO's lifelong protocol
(`run_lifelong`; over seeds `run_lifelong_seeds`; algorithms side by side `lifelong_table`), LIBERO-PRO's
robustness table (`run_robustness`), the episode log and the metrics computed from it. Names resolve on first use."""

from __future__ import annotations

from base_suites.runtime.lazy import lazy_getattr

_LAZY = {
    "evaluate": "elegant.evaluation.runner",
    "episode_start": "elegant.evaluation.runner",
    "open_policy": "elegant.evaluation.runner",
    "open_critic": "elegant.evaluation.runner",
    "collect_rollouts": "elegant.evaluation.rollouts",
    "run_lifelong": "elegant.evaluation.lifelong",
    "run_lifelong_seeds": "elegant.evaluation.lifelong_table",
    "run_robustness": "elegant.evaluation.robustness",
    "lifelong_table": "elegant.evaluation.lifelong_table",
    "EpisodeLog": "elegant.evaluation.episode_log",
    "summarize": "elegant.evaluation.metrics",
    "lifelong_metrics": "elegant.evaluation.metrics",
    "robustness_metrics": "elegant.evaluation.metrics",
    "paired_comparison": "elegant.evaluation.metrics",
    "rate_interval": "elegant.evaluation.metrics",
    "success_with_violation": "elegant.evaluation.metrics",
}

__all__ = sorted(_LAZY)

__getattr__ = lazy_getattr(__name__, globals(), _LAZY)
