"""The elegance critic: offline Cal-QL with TorchRL, exported as plain torch modules for run-time decisions.

Data (`load_transitions`, `make_replay_buffer`) -> loss (`CalQLLoss`) -> training (`train_critic`) ->
artifact (`load` -> `Critic`, whose `bind(metadata)` and `q(state, actions)` JITI calls) -> held-out
quality (`evaluate_critic`).
"""
from critics.artifact import Critic, load, save_critic
from critics.data import TransitionData, load_transitions, make_replay_buffer
from critics.loss import CalQLLoss, CalQLTerms, cql_logsumexp
from critics.networks import TanhGaussianActor, TwinQNetwork
from critics.normalization import Normalization
from critics.quality import auroc, evaluate_critic
from critics.train import TrainConfig, train_critic

__all__ = [
    "CalQLLoss", "CalQLTerms", "Critic", "Normalization", "TanhGaussianActor", "TrainConfig", "TransitionData", "TwinQNetwork",
    "auroc", "cql_logsumexp", "evaluate_critic", "load", "load_transitions", "make_replay_buffer", "save_critic",
    "train_critic",
]
