"""The elegance critic: offline Cal-QL with TorchRL, exported as plain torch modules for run-time decisions.

Data (`load_transitions`, `make_replay_buffer`) -> loss (`CalQLLoss`) -> training (`train_critic`) ->
artifact (`load` -> `Critic`, whose `bind(metadata)` and `q(state, actions)` JITI calls; `load_ensemble` ->
`CriticEnsemble`, critics of bootstrap resamples scored together) -> held-out
quality (`evaluate_critic`: held-out AUROC of Q).
"""

from critics.artifact import Critic, load, save_critic
from critics.data import (
    REWARDS,
    TransitionData,
    action_chunks,
    chunk_transitions,
    explored_mask,
    load_transitions,
    make_replay_buffer,
)
from critics.ensemble import CriticEnsemble, load_ensemble
from critics.loss import BACKUPS, VALUE_LOSSES, CalQLLoss, CalQLTerms, cql_logsumexp
from critics.networks import TanhGaussianActor, TwinQNetwork
from critics.normalization import Normalization
from critics.quality import auroc, evaluate_critic
from critics.train import TrainConfig, train_critic

__all__ = [
    "BACKUPS",
    "CalQLLoss",
    "CalQLTerms",
    "Critic",
    "CriticEnsemble",
    "Normalization",
    "REWARDS",
    "TanhGaussianActor",
    "TrainConfig",
    "TransitionData",
    "TwinQNetwork",
    "VALUE_LOSSES",
    "action_chunks",
    "auroc",
    "chunk_transitions",
    "cql_logsumexp",
    "evaluate_critic",
    "explored_mask",
    "load",
    "load_ensemble",
    "load_transitions",
    "make_replay_buffer",
    "save_critic",
    "train_critic",
]
