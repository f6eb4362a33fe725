"""Base policies: the `Policy` protocol, adapters for callables / LeRobot / TorchRL, the BC-GMM policy, policy
specs (`open_policy`: a directory, an entry point or a server), openpi's websocket protocol both ways
(`OpenPIPolicy`, `serve_policy`), and the lifelong algorithms' training mechanisms (`FineTuning` with a
`replay_memory`, an `ElasticAnchor` or `WeightMasks`).

The BC names load torch on first use (PEP 562 lazy attributes), so importing the protocol and adapters
stays instant for commands that never touch a network.
"""

from __future__ import annotations

from base_suites.runtime.lazy import lazy_getattr
from elegant.policies.adapters import (
    TORCHRL_LIBERO_STATE,
    CallablePolicy,
    LayoutSlice,
    LeRobotPolicy,
    PolicyAdapter,
    StateFn,
    TorchRLPolicy,
    as_policy,
    lerobot_libero_state,
)
from elegant.policies.protocol import (
    ACTION_DIM,
    POLICY_ACTS,
    ChunkedPolicy,
    GaussianCandidates,
    Policy,
    as_action,
    chunk_of,
)

_LAZY = {
    "OpenPIPolicy": "elegant.policies.remote",
    "describe_policy": "elegant.policies.specs",
    "open_policy": "elegant.policies.specs",
    "serve_policy": "elegant.policies.server",
    "BCPolicy": "elegant.policies.bc_policy",
    "load_policy": "elegant.policies.bc_policy",
    "train_policy": "elegant.policies.bc_train",
    "FineTuning": "elegant.policies.bc_train",
    "ElasticAnchor": "elegant.policies.continual",
    "WeightMasks": "elegant.policies.continual",
    "replay_memory": "elegant.policies.continual",
}

__all__ = [
    "ACTION_DIM",
    "BCPolicy",
    "CallablePolicy",
    "ChunkedPolicy",
    "ElasticAnchor",
    "FineTuning",
    "GaussianCandidates",
    "LayoutSlice",
    "LeRobotPolicy",
    "OpenPIPolicy",
    "POLICY_ACTS",
    "Policy",
    "PolicyAdapter",
    "StateFn",
    "TORCHRL_LIBERO_STATE",
    "TorchRLPolicy",
    "WeightMasks",
    "as_action",
    "as_policy",
    "chunk_of",
    "describe_policy",
    "lerobot_libero_state",
    "load_policy",
    "open_policy",
    "replay_memory",
    "serve_policy",
    "train_policy",
]


__getattr__ = lazy_getattr(__name__, globals(), _LAZY)
