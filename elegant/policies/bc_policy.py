"""The trained BC-GMM policy at run time: its actions, GMM candidates, per-episode history.

How the policy acts (`act`, one of POLICY_ACTS):
- "mode" (the default): the mean of the mixture's most likely component, so evaluation is deterministic
  and the policy executes its most common way of doing the task.
- "sample": a full draw from the mixture at every decision, as LIBERO evaluates its own BC policies
  (`dist.sample()` of the GMM head, with `low_eval_noise` off by default). A policy imitating demos of
  mixed quality then executes its sloppier modes as often as it learned them, the setting of
  LIBERO-Elegant's stochastic VLAs. The draws come from their own seeded generator, apart from the
  candidates', so JITI asking for candidates does not change what the base policy executes next.
- "component": a component drawn by its weight, executed at its mean, as LIBERO evaluates with its GMM
  head's `low_eval_noise` on: the policy still picks among the ways of doing the task it learned, but
  executes each without the Gaussian jitter around it.
The `sample` method draws candidates from the full mixture with another seeded generator: what JITI
asks for at critical moments; `log_prob_plans` scores candidates by the mixture's density. Plain torch
modules under `torch.inference_mode` keep one decision well under a millisecond on one CPU thread.

A policy trained with `chunk` > 1 decides a chunk of actions at once (`plan`), executes it open-loop and
decides again when it is used up; between decisions it still sees every observation (`observe`), so its
history window is the same as a per-step policy's. `sample_plans` draws whole chunks from the mixture:
each is one coherent way to carry on (a mode of the demonstrations), not one jittered step.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from annotations import GoalContext
from base_suites.runtime.errors import UserInputError, unknown_choice
from elegant.policies.bc_artifact import read_artifact
from elegant.policies.bc_features import BCFeatures
from elegant.policies.bc_model import BCNet, gmm_component_means, gmm_mode, gmm_nll, gmm_sample
from elegant.policies.protocol import (
    ACTION_DIM,
    DEFAULT_POLICY_ACT,
    POLICY_ACTS,
    ExecutesPlans,
    Observation,
    check_count,
)

_ACT_STREAM = 0x5A17  # offsets the execution generator's seed from the candidates' (same episode seed)


class BCPolicy(ExecutesPlans):
    """A `ChunkedPolicy` over the env's low-dimensional state (see module docstring); with `chunk` 1 it
    decides every step. Its candidates are draws from its own mixture.

    Call `reset(env.metadata)` at the start of each episode: it clears the history and the action queue,
    selects the task and refuses an env whose observation layout differs from the training data. A
    single-task policy also works without metadata, checking only the state width.
    """

    candidate_source = "the policy's samples"

    def __init__(
        self,
        net: BCNet,
        features: BCFeatures,
        *,
        path: str = "policy",
        seed: int = 0,
        config: Mapping[str, Any] | None = None,
        act: str = DEFAULT_POLICY_ACT,
    ) -> None:
        if act not in POLICY_ACTS:
            raise unknown_choice("policy act", act, POLICY_ACTS)
        self.act = act
        self.net = net.eval()
        self.features = features
        self.path = path
        self.config = dict(config or {})
        self.chunk = int(self.config.get("model", {}).get("chunk", 1))
        self.device = torch.device("cpu")
        self.generator = torch.Generator()
        self._act_generator = torch.Generator()
        self._window: deque[np.ndarray] = deque(maxlen=features.history)
        self._queue: deque[np.ndarray] = deque()
        self._last_state: np.ndarray | None = None
        self.task: str | GoalContext | None = None  # what `features.encode` reads: a task key or a goal plan
        self.reset(seed=seed)

    @property
    def tasks(self) -> list[str]:
        return list(self.features.encoder.tasks)

    def reset(self, metadata: Mapping[str, Any] | None = None, *, seed: int | None = None) -> None:
        self._window.clear()
        self._queue.clear()
        self._last_state = None
        if metadata is not None:  # a task key, or the episode's goal-relative plan
            self.task = self.features.context(metadata, self.path)
        elif len(self.tasks) == 1 and self.features.encoder.kind == "task-onehot":
            self.task = self.tasks[0]
        else:
            self.task = None
        if seed is not None:
            self._seed_generators(int(seed))

    def _seed_generators(self, seed: int) -> None:
        """Restart the candidates' and the execution's streams from `seed` (kept for `to`)."""
        self._seed = seed
        self.generator.manual_seed(seed)
        self._act_generator.manual_seed(seed + _ACT_STREAM)

    def to(self, device: str | torch.device) -> BCPolicy:
        """Run the network and the draws on `device` from now on (the CPU by default). A GPU draws from its
        own generators, seeded alike, so its candidates differ from the CPU's: a run records its device."""
        self.device = torch.device(device)
        self.net.to(self.device)
        self.generator = torch.Generator(self.device)
        self._act_generator = torch.Generator(self.device)
        self._seed_generators(self._seed)
        return self

    def _state(self, obs: Observation) -> np.ndarray:
        if "state" not in obs:
            raise UserInputError(
                f"{self.path}: the observation has no 'state' entry; make the env with obs='lowdim' or 'both'"
            )
        return np.asarray(obs["state"], dtype=np.float64)

    def _push(self, state: np.ndarray) -> None:
        if self.task is None:
            raise UserInputError(
                f"{self.path}: a multi-task or goal-relative policy needs reset(env.metadata) before acting"
            )
        width = self.features.width(self.task)
        if state.shape != (width,):
            raise UserInputError(
                f"{self.path}: observation 'state' has shape {state.shape}; task "
                f"{getattr(self.task, 'task', self.task)} expects ({width},)"
            )
        encoded = self.features.encode(state, self.task)
        if not self._window:
            self._window.extend([encoded] * self.features.history)  # episode start: repeat the first state
        else:
            self._window.append(encoded)
        self._last_state = state.copy()

    def _distribution(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        window = torch.from_numpy(np.stack(self._window)).unsqueeze(0).to(self.device)
        return self.net(self.features.flatten_window(window))

    def _see(self, obs: Observation) -> None:
        """Step the history with `obs` unless it is the observation seen last (a second call for one step)."""
        state = self._state(obs)
        if self._last_state is None or not np.array_equal(self._last_state, state):
            self._push(state)

    def observe(self, obs: Observation) -> None:
        """See an observation at which no decision is taken (inside a chunk)."""
        self._push(self._state(obs))

    def plan(self, obs: Observation) -> np.ndarray:
        """The decision at `obs`: (chunk, 7) actions, the mean of the mixture's most likely component, with
        `act="sample"` one draw from the mixture, with `act="component"` the mean of a drawn component."""
        self._push(self._state(obs))
        with torch.inference_mode():
            logits, means, stds = self._distribution()
            if self.act == "sample":
                action = gmm_sample(logits, means, stds, 1, self._act_generator)[0]
            elif self.act == "component":
                action = gmm_component_means(logits, means, 1, self._act_generator)[0]
            else:
                action = gmm_mode(logits, means)[0]
            return action.cpu().double().numpy().reshape(self.chunk, ACTION_DIM)

    def sample_plans(self, obs: Observation, n: int) -> np.ndarray:
        """n chunks (n, chunk, 7) drawn from the mixture for the decision at `obs`; does not step the history
        again right after `plan(obs)` or `__call__(obs)`."""
        n = check_count(n)
        self._see(obs)
        with torch.inference_mode():
            logits, means, stds = self._distribution()
            return (
                gmm_sample(logits, means, stds, n, self.generator)
                .cpu()
                .double()
                .numpy()
                .reshape(n, self.chunk, ACTION_DIM)
            )

    def log_prob_plans(self, obs: Observation, plans: np.ndarray) -> np.ndarray:
        """The mixture's log-density (n,) of each of `plans` (n, chunk, 7) at the decision at `obs` (what
        JITI's mode "likelihood" ranks candidates by); does not step the history again right after
        `plan(obs)` or `__call__(obs)`."""
        self._see(obs)
        with torch.inference_mode():
            logits, means, stds = self._distribution()
            flat = torch.as_tensor(np.asarray(plans).reshape(len(plans), -1), dtype=means.dtype, device=self.device)
            return (-gmm_nll(logits, means, stds, flat)).cpu().double().numpy()

    def sample(self, obs: Observation, n: int) -> np.ndarray:
        """n actions for this step: the first actions of n sampled plans (`sample_plans`)."""
        return self.sample_plans(obs, n)[:, 0]


def load_policy(path: str, *, seed: int = 0, act: str = DEFAULT_POLICY_ACT) -> BCPolicy:
    """Load a directory written by `train_policy` (refused in one line if missing, corrupt or foreign),
    acting as `act` says (see the module docstring)."""
    net, features, config = read_artifact(str(path))
    return BCPolicy(net, features, path=str(path), seed=seed, config=config, act=act)
