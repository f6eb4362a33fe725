"""Adapters that turn the policies people bring into a `Policy`.

Three kinds are supported: plain callables obs -> action, LeRobot-style policies (`select_action(batch)`
and `reset()`), and TorchRL policies (a `tensordict.nn.TensorDictModule` reading ("observation",
"state") and writing "action", the schema of `torchrl.envs.LiberoEnv`). Each adapter produces candidates
the way its policy allows: a stochastic TorchRL module samples its own distribution; everything else gets
clipped Gaussian perturbations around its action, with the action itself as candidate 0.

Stateful policies (LeRobot's action queues, history windows) must not be stepped twice for one env
step, so `sample(obs, n)` right after `__call__(obs)` reuses the action of that call instead of asking
the policy again. torch and tensordict are imported only by the adapters that need them.
"""

from __future__ import annotations

import inspect
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from base_suites.rotations import quat_to_axis_angle
from base_suites.runtime.errors import UserInputError
from elegant.policies.protocol import (
    ACTION_DIM,
    ACTION_HIGH,
    ACTION_LOW,
    DEFAULT_NOISE_SCALE,
    GaussianCandidates,
    Observation,
    Policy,
    as_action,
    check_count,
)

StateFn = Callable[[np.ndarray, Mapping[str, Any] | None], np.ndarray]
"""Maps (obs["state"], env metadata or None) to the state vector a foreign policy expects."""


class LayoutSlice:
    """A `StateFn` that picks named entries of the env's state layout, in the given order.

    Foreign policies were trained on their own proprioceptive vector (TorchRL's LiberoEnv concatenates
    eef position, eef quaternion and gripper joints); the env's full state also holds every object's
    pose, so the entries are looked up by name in `metadata["state_layout"]` rather than by position.
    """

    def __init__(self, *names: str) -> None:
        if not names:
            raise UserInputError("LayoutSlice needs at least one state entry name")
        self.names = tuple(names)

    def __call__(self, state: np.ndarray, metadata: Mapping[str, Any] | None) -> np.ndarray:
        if metadata is None or "state_layout" not in metadata:
            raise UserInputError("selecting state entries needs the env metadata: call reset(env.metadata) first")
        offsets, start = {}, 0
        for name, size in metadata["state_layout"]:
            offsets[name] = (start, start + int(size))
            start += int(size)
        missing = [n for n in self.names if n not in offsets]
        if missing:
            raise UserInputError(f"state_layout has no entries {missing}; it has: {', '.join(offsets)}")
        return np.concatenate([state[slice(*offsets[n])] for n in self.names])


TORCHRL_LIBERO_STATE = LayoutSlice("robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos")
"""The 9-D ("observation", "state") of `torchrl.envs.LiberoEnv` with its default `proprio_keys`."""


def lerobot_libero_state(state: np.ndarray, metadata: Mapping[str, Any] | None) -> np.ndarray:
    """LeRobot's 8-D LIBERO "observation.state": eef position, eef axis-angle, gripper joints."""
    pos, quat, grip = np.split(TORCHRL_LIBERO_STATE(state, metadata), [3, 7])
    return np.concatenate([pos, quat_to_axis_angle(quat), grip])


class PolicyAdapter:
    """Shared bookkeeping: one action per step, candidates for that step, episode reset.

    Subclasses implement `_act(obs)` (ask the wrapped policy for one action) and may override
    `_candidates(obs, action, n)` and `_reset(metadata)`.
    """

    name = "policy"
    candidate_source = "Gaussian noise"  # where JITI's candidates come from (a run's config records it)

    def __init__(self, *, noise_scale: float = DEFAULT_NOISE_SCALE, seed: int = 0) -> None:
        self.noise = GaussianCandidates(noise_scale, seed)
        self.metadata: Mapping[str, Any] | None = None
        self._last_obs: dict[str, np.ndarray] | None = None
        self._last_action: np.ndarray | None = None

    def __call__(self, obs: Observation) -> np.ndarray:
        action = as_action(self._act(obs), self.name)
        self._last_obs = {k: np.array(v, copy=True) for k, v in obs.items()}
        self._last_action = action
        return action.copy()

    def sample(self, obs: Observation, n: int) -> np.ndarray:
        n = check_count(n)
        action = self._last_action if self._is_last(obs) else self(obs)
        return self._candidates(obs, action, n)

    def reset(self, metadata: Mapping[str, Any] | None = None, *, seed: int | None = None) -> None:
        self.metadata = metadata
        self._last_obs = self._last_action = None
        if seed is not None:
            self.noise.reseed(seed)
        self._reset(metadata)

    def _is_last(self, obs: Observation) -> bool:
        last = self._last_obs
        return last is not None and last.keys() == obs.keys() and all(np.array_equal(last[k], obs[k]) for k in last)

    def _act(self, obs: Observation) -> Any:
        raise NotImplementedError

    def _candidates(self, obs: Observation, action: np.ndarray, n: int) -> np.ndarray:
        return self.noise(action, n)

    def _reset(self, metadata: Mapping[str, Any] | None) -> None:
        """Nothing to reset unless the wrapped policy has episode state."""

    @property
    def instruction(self) -> str:
        return str((self.metadata or {}).get("instruction", ""))

    def _state(self, obs: Observation, state_fn: StateFn | None) -> np.ndarray:
        if "state" not in obs:
            raise UserInputError(
                f"{self.name}: the observation has no 'state' entry; make the env with obs='lowdim' or 'both'"
            )
        state = np.asarray(obs["state"], dtype=np.float64)
        return state if state_fn is None else np.asarray(state_fn(state, self.metadata), dtype=np.float64)


def _check_candidates(value: Any, n: int, source: str) -> np.ndarray:
    out = np.asarray(value, dtype=np.float64)
    if out.shape != (n, ACTION_DIM):
        raise UserInputError(f"{source}.sample(obs, {n}) returned shape {out.shape}; expected ({n}, {ACTION_DIM})")
    return np.clip(out, ACTION_LOW, ACTION_HIGH)


class CallablePolicy(PolicyAdapter):
    """A callable obs -> action; uses its own `sample(obs, n)` and `reset(...)` when it has them."""

    name = "callable policy"

    def __init__(
        self, fn: Callable[[Observation], Any], *, noise_scale: float = DEFAULT_NOISE_SCALE, seed: int = 0
    ) -> None:
        super().__init__(noise_scale=noise_scale, seed=seed)
        self.fn = fn
        sampler = getattr(fn, "sample", None)
        self._own_sample = sampler if callable(sampler) else None
        self.stochastic = bool(getattr(fn, "stochastic", False))
        if self._own_sample is not None:
            self.candidate_source = "the policy's samples"
        elif self.stochastic:
            self.candidate_source = "repeated calls"
        reset = getattr(fn, "reset", None)
        self._own_reset = reset if callable(reset) else None
        self._reset_takes_metadata = self._own_reset is not None and _accepts_argument(self._own_reset)
        self._reset_takes_seed = self._own_reset is not None and _accepts_keyword(self._own_reset, "seed")

    def _act(self, obs: Observation) -> Any:
        return self.fn(obs)

    def sample(self, obs: Observation, n: int) -> np.ndarray:
        if self._own_sample is None:
            return super().sample(obs, n)
        n = check_count(n)
        return _check_candidates(self._own_sample(obs, n), n, type(self.fn).__name__)

    def _candidates(self, obs: Observation, action: np.ndarray, n: int) -> np.ndarray:
        """A stochastic callable (`fn.stochastic` true) is asked n - 1 more times; candidate 0 is its action."""
        if not self.stochastic:
            return super()._candidates(obs, action, n)
        return np.stack([action] + [as_action(self.fn(obs), self.name) for _ in range(n - 1)])

    def reset(self, metadata: Mapping[str, Any] | None = None, *, seed: int | None = None) -> None:
        self._seed = seed
        super().reset(metadata, seed=seed)

    def _reset(self, metadata: Mapping[str, Any] | None) -> None:
        if self._own_reset is None:
            return
        seeded = {"seed": self._seed} if self._reset_takes_seed else {}  # seeds reach a policy that takes them
        self._own_reset(metadata, **seeded) if self._reset_takes_metadata else self._own_reset(**seeded)


def _accepts_keyword(fn: Callable[..., Any], name: str) -> bool:
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return False
    return name in params or any(p.kind is p.VAR_KEYWORD for p in params.values())


def _accepts_argument(fn: Callable[..., Any]) -> bool:
    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):
        return False
    return any(p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD, p.VAR_POSITIONAL) for p in params)


class LeRobotPolicy(PolicyAdapter):
    """A LeRobot-style policy: `select_action(batch)` on a batch of one, `reset()` at episode start.

    The batch holds `state_key` (float32, shape (1, D)), the instruction under "task" (a list with one
    string, as LeRobot's env wrappers add it) and the images as (1, 3, H, W) float32 in [0, 1]. With the
    env's `obs="vla"` these are LeRobot's LIBERO keys: `image_key` the agentview image, `wrist_image_key`
    the wrist image (both rotated as LeRobot's LIBERO env feeds them) and the 8-D `vla_state` as the state;
    otherwise the upright "agentview" image, if any, under `image_key` and the env state through
    `state_fn` (e.g. `lerobot_libero_state` for LeRobot's LIBERO policies).
    """

    name = "LeRobot policy"

    def __init__(
        self,
        policy: Any,
        *,
        state_key: str = "observation.state",
        image_key: str = "observation.images.image",
        wrist_image_key: str = "observation.images.image2",
        state_fn: StateFn | None = None,
        device: str = "cpu",
        noise_scale: float = DEFAULT_NOISE_SCALE,
        seed: int = 0,
    ) -> None:
        import torch

        super().__init__(noise_scale=noise_scale, seed=seed)
        self._torch = torch
        self.policy = policy
        self.state_key, self.image_key, self.state_fn, self.device = state_key, image_key, state_fn, device
        self.wrist_image_key = wrist_image_key

    def _act(self, obs: Observation) -> Any:
        torch = self._torch
        vla = "vla_state" in obs and self.state_fn is None
        state = np.asarray(obs["vla_state"], dtype=np.float64) if vla else self._state(obs, self.state_fn)
        batch: dict[str, Any] = {
            self.state_key: torch.as_tensor(state, dtype=torch.float32, device=self.device).unsqueeze(0),
            "task": [self.instruction],
        }
        images = {"agentview": self.image_key}
        if vla:
            images = {"image": self.image_key, "wrist_image": self.wrist_image_key}
        for name, key in images.items():
            if name in obs:
                image = torch.as_tensor(np.ascontiguousarray(obs[name]), device=self.device)
                batch[key] = image.permute(2, 0, 1).unsqueeze(0).to(torch.float32) / 255.0
        with torch.inference_mode():
            action = self.policy.select_action(batch)
        return action.detach().cpu().numpy()

    def _reset(self, metadata: Mapping[str, Any] | None) -> None:
        reset = getattr(self.policy, "reset", None)
        if callable(reset):
            reset()


class TorchRLPolicy(PolicyAdapter):
    """A TorchRL policy: a TensorDictModule reading `state_key` and writing `action_key`.

    Keys follow `torchrl.envs.LiberoEnv`: nested ("observation", "state") and a root "action"; the
    instruction is set under `instruction_key` ("language_instruction") when the module reads it. A
    probabilistic module (`ProbabilisticTensorDictSequential` / `ProbabilisticTensorDictModule`) acts
    with its deterministic sample (its mode or mean) and draws candidates from its own distribution under
    a seeded torch RNG; any other module gets Gaussian perturbations.
    """

    name = "TorchRL policy"

    def __init__(
        self,
        module: Any,
        *,
        state_key: str | tuple[str, ...] = ("observation", "state"),
        action_key: str | tuple[str, ...] = "action",
        instruction_key: str = "language_instruction",
        state_fn: StateFn | None = None,
        noise_scale: float = DEFAULT_NOISE_SCALE,
        seed: int = 0,
    ) -> None:
        import torch
        from tensordict import TensorDict
        from tensordict.nn import (
            InteractionType,
            ProbabilisticTensorDictModule,
            ProbabilisticTensorDictSequential,
            set_interaction_type,
        )

        super().__init__(noise_scale=noise_scale, seed=seed)
        self._torch, self._TensorDict = torch, TensorDict
        self._interaction, self._set_interaction = InteractionType, set_interaction_type
        self.module = module
        self.state_key, self.action_key, self.state_fn = state_key, action_key, state_fn
        self.stochastic = isinstance(module, (ProbabilisticTensorDictModule, ProbabilisticTensorDictSequential))
        self.candidate_source = "the policy's samples" if self.stochastic else "Gaussian noise"
        self._reads_instruction = instruction_key in _flat_keys(getattr(module, "in_keys", ()))
        self.instruction_key = instruction_key

    def _run(self, obs: Observation, batch: Sequence[int], interaction: Any) -> Any:
        torch = self._torch
        state = torch.as_tensor(self._state(obs, self.state_fn), dtype=torch.float32)
        td = self._TensorDict({}, batch_size=list(batch))
        td.set(self.state_key, state.expand(*batch, state.shape[-1]))
        if self._reads_instruction:
            td.set_non_tensor(self.instruction_key, self.instruction)
        with torch.inference_mode(), self._set_interaction(interaction):
            return self.module(td).get(self.action_key).detach().cpu().numpy()

    def _act(self, obs: Observation) -> Any:
        return self._run(obs, [], self._interaction.DETERMINISTIC)

    def _candidates(self, obs: Observation, action: np.ndarray, n: int) -> np.ndarray:
        if not self.stochastic:
            return super()._candidates(obs, action, n)
        if n == 1:
            return action[None].copy()
        torch = self._torch
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(int(self.noise.rng.integers(2**63)))
            drawn = self._run(obs, [n - 1], self._interaction.RANDOM)
        return np.clip(
            np.concatenate([action[None], np.asarray(drawn, dtype=np.float64).reshape(n - 1, ACTION_DIM)]),
            ACTION_LOW,
            ACTION_HIGH,
        )


def _flat_keys(keys: Sequence[Any]) -> set[str]:
    return {k if isinstance(k, str) else ".".join(k) if len(k) > 1 else k[0] for k in keys}


def _is_full_policy(obj: Any) -> bool:
    if not isinstance(obj, Policy):
        return False
    try:
        return "seed" in inspect.signature(obj.reset).parameters
    except (TypeError, ValueError):
        return False


def as_policy(obj: Any, *, noise_scale: float = DEFAULT_NOISE_SCALE, seed: int = 0) -> Policy:
    """Adapt a supported object to the `Policy` protocol (objects that already implement it pass through).

    Checked in order: a full `Policy`; a TorchRL `TensorDictModule`; an object with `select_action`
    (LeRobot); any callable obs -> action. For adapter options (state keys, `state_fn`) construct
    `TorchRLPolicy` / `LeRobotPolicy` directly.
    """
    if _is_full_policy(obj):
        return obj
    if "tensordict" in sys.modules:  # a TensorDictModule cannot exist unless tensordict was imported
        from tensordict.nn import TensorDictModuleBase

        if isinstance(obj, TensorDictModuleBase):
            return TorchRLPolicy(obj, noise_scale=noise_scale, seed=seed)
    if callable(getattr(obj, "select_action", None)):
        return LeRobotPolicy(obj, noise_scale=noise_scale, seed=seed)
    if callable(obj):
        return CallablePolicy(obj, noise_scale=noise_scale, seed=seed)
    raise UserInputError(
        f"cannot use a {type(obj).__name__} as a policy: expected a callable obs -> action, an object with "
        "select_action(batch) (LeRobot), or a tensordict TensorDictModule (TorchRL)"
    )
