"""Base policies: the `Policy` protocol, adapters for callables / LeRobot / TorchRL, and the BC-GMM policy.

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
    "BCPolicy": "elegant.policies.bc_policy",
    "load_policy": "elegant.policies.bc_policy",
    "train_policy": "elegant.policies.bc_train",
}

__all__ = [
    "ACTION_DIM",
    "BCPolicy",
    "CallablePolicy",
    "ChunkedPolicy",
    "GaussianCandidates",
    "LayoutSlice",
    "LeRobotPolicy",
    "POLICY_ACTS",
    "Policy",
    "PolicyAdapter",
    "StateFn",
    "TORCHRL_LIBERO_STATE",
    "TorchRLPolicy",
    "as_action",
    "as_policy",
    "chunk_of",
    "lerobot_libero_state",
    "load_policy",
    "train_policy",
]


__getattr__ = lazy_getattr(__name__, globals(), _LAZY)
