"""What the rest of the project expects from a base policy.

JITI, the evaluation runner and the CLI only ever talk to a `Policy`: a callable from the env's
observation dict to one 7-D action in [-1, 1], plus `sample(obs, n)` for candidate actions at critical
moments and `reset(metadata, seed=)` at episode start. User objects need only be callable (or a LeRobot
or TorchRL policy); `elegant.policies.as_policy` supplies the rest. The Gaussian candidate sampler used
for deterministic policies lives here because every adapter shares it.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from typing import Any, Literal, Protocol, get_args, runtime_checkable

import numpy as np

from base_suites.runtime.errors import UserInputError

ACTION_DIM = 7
ACTION_LOW = -1.0
ACTION_HIGH = 1.0
# how a BC policy acts: its mixture's most likely mean, a draw, a drawn component's mean (elegant.policies.bc_policy)
PolicyAct = Literal["mode", "sample", "component"]
POLICY_ACTS: tuple[str, ...] = get_args(PolicyAct)
POLICY_ACT_HELP = (
    "how the BC policy acts: its mixture's most likely mean (mode, deterministic), a draw from the mixture at every "
    "decision (sample, as LIBERO runs its BC policies) or the mean of a drawn component (component, LIBERO's "
    "low_eval_noise)"
)
DEFAULT_POLICY_ACT = "mode"  # also what runs, gates and chains recorded before the act was a setting
# std of the Gaussian candidates around a deterministic policy's action: declared once for every adapter and
# for `JITIConfig.noise_scale`
DEFAULT_NOISE_SCALE = 0.1

Observation = Mapping[str, np.ndarray]


@runtime_checkable
class Policy(Protocol):
    """A base policy as JITI and the evaluation runner use it.

    `__call__(obs)` is the policy's step: it may advance internal state (history, action queues).
    `sample(obs, n)` returns `n` candidate actions for the same step without advancing it again when
    called right after `__call__(obs)` with that observation. `reset(metadata, seed=)` starts an episode:
    `metadata` is the env's `metadata` dict (suite, task_index, instruction, state_layout, ...) so a
    multi-task policy knows its task and can refuse an observation layout it was not trained on; `seed`
    reseeds candidate sampling so an episode's candidates do not depend on the episodes before it.
    """

    def __call__(self, obs: Observation) -> np.ndarray: ...

    def sample(self, obs: Observation, n: int) -> np.ndarray: ...

    def reset(self, metadata: Mapping[str, Any] | None = None, *, seed: int | None = None) -> None: ...


@runtime_checkable
class ChunkedPolicy(Policy, Protocol):
    """A policy that decides `chunk` actions at a time and executes them open-loop (action chunking, as
    VLA policies such as pi0, SmolVLA and OpenVLA-OFT do).

    `plan(obs)` is the decision at `obs`: (chunk, 7) actions, the first for this step. `sample_plans(obs, n)`
    returns n alternative chunks (n, chunk, 7) for the same decision, without stepping the policy again
    right after `plan(obs)`. `observe(obs)` shows the policy an observation at which it takes no decision
    (inside a chunk), so a history window stays complete. `__call__` executes plans one action per step.
    JITI decides among whole chunks of such a policy, with a critic trained on chunks of the same length.
    """

    chunk: int

    def plan(self, obs: Observation) -> np.ndarray: ...

    def sample_plans(self, obs: Observation, n: int) -> np.ndarray: ...

    def observe(self, obs: Observation) -> None: ...


def chunk_of(policy: Any) -> int:
    """How many actions one decision of `policy` commits to (1 unless it is a `ChunkedPolicy`)."""
    chunk = int(getattr(policy, "chunk", 1))
    if chunk > 1 and not isinstance(policy, ChunkedPolicy):
        raise UserInputError(
            f"{type(policy).__name__} has chunk={chunk} but lacks plan, sample_plans or observe (see ChunkedPolicy)"
        )
    if chunk < 1:
        raise UserInputError(f"{type(policy).__name__}.chunk must be >= 1, got {chunk}")
    return chunk


def as_action(value: Any, source: str = "policy") -> np.ndarray:
    """One action as a float64 (7,) array clipped to the action bounds; refuse any other shape, and NaN or
    infinity (which MuJoCo would only warn about)."""
    action = np.asarray(value, dtype=np.float64).reshape(-1)
    if action.shape != (ACTION_DIM,):
        raise UserInputError(f"{source} returned an action of shape {np.shape(value)}; expected ({ACTION_DIM},)")
    if not np.isfinite(action).all():
        raise UserInputError(f"{source} returned an action holding NaN or infinity: {action.tolist()}")
    return np.clip(action, ACTION_LOW, ACTION_HIGH)


def check_count(n: int) -> int:
    """Validate a requested number of candidates."""
    if int(n) != n or n < 1:
        raise UserInputError(f"number of candidate actions must be a positive integer, got {n!r}")
    return int(n)


class ExecutesPlans:
    """A `ChunkedPolicy`'s `__call__`, shared by the chunked policies: the first action of a new `plan`
    when the last chunk is used up, else the chunk's next action (the observation then only `observe`d).
    Needs `self._queue`, a deque of the current chunk's remaining actions."""

    _queue: Any

    def __call__(self, obs: Observation) -> np.ndarray:
        if self._queue:
            self.observe(obs)
        else:
            self._queue.extend(self.plan(obs))
        return self._queue.popleft()


class GaussianCandidates:
    """Candidates for a deterministic policy: its action plus clipped Gaussian perturbations.

    Candidate 0 is the unperturbed action, so selecting among candidates can always fall back to what
    the policy would have done. The generator is seeded, so the same seed gives the same candidates.
    """

    def __init__(self, scale: float = DEFAULT_NOISE_SCALE, seed: int = 0) -> None:
        if not scale >= 0:
            raise UserInputError(f"candidate noise scale must be >= 0, got {scale!r}")
        self.scale = float(scale)
        self.reseed(seed)

    def reseed(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def __call__(self, action: np.ndarray, n: int) -> np.ndarray:
        n = check_count(n)
        out = np.repeat(np.asarray(action, dtype=np.float64).reshape(1, ACTION_DIM), n, axis=0)
        out[1:] += self.rng.normal(0.0, self.scale, size=(n - 1, ACTION_DIM))
        return np.clip(out, ACTION_LOW, ACTION_HIGH)


def add_policy_act_argument(parser: argparse.ArgumentParser) -> None:
    """`--policy-act` for a command without a config (`elegant serve-policy`), with the configs' help."""
    parser.add_argument("--policy-act", choices=POLICY_ACTS, default=DEFAULT_POLICY_ACT, help=POLICY_ACT_HELP)
