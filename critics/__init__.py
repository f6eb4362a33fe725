"""The elegance critic: offline Cal-QL with TorchRL, exported as plain torch modules for run-time decisions.

Settings (`TrainConfig`, torch-free) -> data (`load_transitions`, `make_replay_buffer`) -> loss
(`CalQLLoss`) -> training (`train_critic`) -> artifact (`load` -> `Critic`, whose `bind(metadata)` and
`q(state, actions)` JITI calls; `load_ensemble` -> `CriticEnsemble`, critics of bootstrap resamples
scored together) -> held-out quality (`evaluate_critic`: held-out AUROC of Q). Names resolve on first
use, so reading the settings does not load torch.
"""

from __future__ import annotations

from base_suites.runtime.lazy import lazy_getattr

_LAZY = {
    "BACKUPS": "critics.config",
    "REWARDS": "critics.config",
    "VALUE_LOSSES": "critics.config",
    "TrainConfig": "critics.config",
    "Critic": "critics.artifact",
    "load": "critics.artifact",
    "save_critic": "critics.artifact",
    "CriticEnsemble": "critics.ensemble",
    "load_ensemble": "critics.ensemble",
    "TransitionData": "critics.data",
    "action_chunks": "critics.data",
    "chunk_transitions": "critics.data",
    "explored_mask": "critics.data",
    "load_transitions": "critics.data",
    "make_replay_buffer": "critics.data",
    "CalQLLoss": "critics.loss",
    "CalQLTerms": "critics.loss",
    "cql_logsumexp": "critics.loss",
    "TanhGaussianActor": "critics.networks",
    "TwinQNetwork": "critics.networks",
    "Normalization": "critics.normalization",
    "auroc": "critics.quality",
    "evaluate_critic": "critics.quality",
    "train_critic": "critics.train",
}

__all__ = sorted(_LAZY)

__getattr__ = lazy_getattr(__name__, globals(), _LAZY)
