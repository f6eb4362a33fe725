"""The trained critic on disk and at run time.

A critic directory holds `critic.pt` (the `TwinQNetwork` state_dict) and `critic.json` (how to rebuild
and feed it: network config, the `TaskFeatureEncoder` layouts, observation normalisation, action
bounds, gamma, the training config and the library versions). `load(dir)` returns a `Critic`, which
scores actions with the module's plain tensors under `torch.inference_mode`, without TensorDicts,
because JITI calls it inside the control loop (target: <= 150 us for one state and 16 actions on one
thread).
"""
from __future__ import annotations

import io
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from annotations import TaskFeatureEncoder
from base_suites.atomic import atomic_write, atomic_write_json, library_versions, read_artifact_config
from base_suites.errors import UserInputError
from critics.networks import TwinQNetwork
from critics.normalization import Normalization

CRITIC_FORMAT = "libero-elegant/critic/1"
WEIGHTS_FILE = "critic.pt"
CONFIG_FILE = "critic.json"


def atomic_torch_save(path: str, obj: Any) -> None:
    """torch.save through `base_suites.atomic`: a kill mid-write leaves the previous file intact."""
    buffer = io.BytesIO()
    torch.save(obj, buffer)
    atomic_write(path, buffer.getvalue())


@dataclass(frozen=True)
class _Binding:
    """One task's observation encoding folded into the critics' first layer.

    The normalised encoding of a state x of the task is t + P(x / std), where t (the encoding of a zero
    state: padding, task one-hot, -mean/std) is fixed and P pads into the first `state_size` columns.
    So the first layer's state part is bias + t @ W + x @ (W[:state_size] / std): `q` then needs no
    encoding or normalisation work beyond one small matmul.
    """

    task: str
    state_size: int
    state_weight: torch.Tensor  # (state_size, C * H)
    state_bias: torch.Tensor  # (C * H,)


class Critic:
    """An elegance critic: Q(s, a) = min over the twin critics, for states of the task it is bound to.

    `q` evaluates the saved `TwinQNetwork` with its weights rearranged once at construction (both critics'
    first layers side by side, the task encoding folded in at `bind`), because JITI calls it every step:
    the same numbers as `network(obs, actions)` on encoded, normalised inputs, in about ten torch ops.
    """

    def __init__(
        self,
        network: TwinQNetwork,
        encoder: TaskFeatureEncoder,
        normalization: Normalization,
        config: Mapping[str, Any] | None = None,
        path: str = "critic",
    ) -> None:
        self.network = network.eval().requires_grad_(False)
        self.encoder = encoder
        self.normalization = normalization
        self.config = dict(config or {})
        self.path = path
        self._center = normalization.action_center.astype(np.float32)
        self._inv_half = (1.0 / normalization.action_half_range).astype(np.float32)
        n, a, width = network.action_weight.shape
        self._n_critics, self._width = n, width
        self._action_weight = network.action_weight.detach().permute(1, 0, 2).reshape(1, a, n * width)
        self._middle = [(w.detach(), b.detach()) for w, b in zip(list(network.weights)[:-1], list(network.biases)[:-1])]
        self._last_row = network.weights[-1].detach().transpose(1, 2)  # (C, 1, H)
        self._last_bias = network.biases[-1].detach().view(n, 1)
        self._binding: _Binding | None = None

    @property
    def tasks(self) -> list[str]:
        return list(self.encoder.tasks)

    def _binding_for(self, metadata: Mapping[str, Any]) -> _Binding:
        key = self.encoder.check_env(metadata, self.path)
        size = sum(s for _, s in self.encoder.layouts[key])
        zero_state = torch.from_numpy(self.normalization.observations(self.encoder.encode(np.zeros(size, dtype=np.float32), key)))
        obs_weight = self.network.obs_weight.detach()  # (C, D, H)
        n, width = self._n_critics, self._width
        bias = self.network.first_bias.detach().view(n, width) + torch.einsum("d,cdh->ch", zero_state, obs_weight)
        inv_std = torch.from_numpy(1.0 / self.normalization.obs_std[:size])
        weight = obs_weight[:, :size, :] * inv_std[None, :, None]
        return _Binding(key, size, weight.permute(1, 0, 2).reshape(size, n * width).contiguous(), bias.reshape(n * width))

    def bind(self, metadata: Mapping[str, Any]) -> "Critic":
        """Score states of the env described by `metadata` (suite, task_index, state_layout) from now on.

        Refuses (UserInputError) a task the critic was not trained on or a different observation layout.
        """
        self._binding = self._binding_for(metadata)
        return self

    def q(self, state: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Q of raw env actions: state (D,) with actions (N, 7) -> (N,); states (B, D) with (B, N, 7) -> (B, N)."""
        if self._binding is None:
            raise RuntimeError("Critic.q needs a task: call critic.bind(env.metadata) first")
        return self._score(self._binding, state, actions)

    def _score(self, b: _Binding, state: np.ndarray, actions: np.ndarray) -> np.ndarray:
        state = np.asarray(state, dtype=np.float32)
        actions = np.asarray(actions, dtype=np.float32)
        single = state.ndim == 1
        if single:
            state, actions = state[None], actions[None]
        if state.ndim != 2 or state.shape[1] != b.state_size or actions.ndim != 3 or actions.shape[0] != state.shape[0]:
            raise UserInputError(
                f"{self.path}: Critic.q expects state ({b.state_size},) with actions (N, A) or states (B, {b.state_size}) "
                f"with actions (B, N, A) for task {b.task}; got {state.shape} and {actions.shape}"
            )
        batch, k, a = actions.shape
        scaled = np.clip((actions - self._center) * self._inv_half, -1.0, 1.0)
        with torch.inference_mode():
            per_state = torch.addmm(b.state_bias, torch.from_numpy(state), b.state_weight)
            h = torch.baddbmm(per_state.unsqueeze(1), torch.from_numpy(scaled), self._action_weight.expand(batch, a, -1)).relu_()
            h = h.view(batch * k, self._n_critics, self._width).transpose(0, 1)
            for w, bias in self._middle:
                h = torch.baddbmm(bias, h, w).relu_()
            q = ((h * self._last_row).sum(-1) + self._last_bias).amin(0).view(batch, k).numpy()
        return q[0] if single else q


def save_critic(
    out_dir: str,
    network: TwinQNetwork,
    encoder: TaskFeatureEncoder,
    normalization: Normalization,
    *,
    gamma: float,
    training: Mapping[str, Any],
) -> str:
    """Write critic.pt and critic.json into out_dir (each atomically; the weights first)."""
    os.makedirs(out_dir, exist_ok=True)
    atomic_torch_save(os.path.join(out_dir, WEIGHTS_FILE), {k: v.detach().clone() for k, v in network.state_dict().items()})
    atomic_write_json(os.path.join(out_dir, CONFIG_FILE), {
        "format": CRITIC_FORMAT,
        "network": network.config(),
        "encoder": encoder.to_dict(),
        "normalization": normalization.to_dict(),
        "gamma": float(gamma),
        "training": dict(training),
        "versions": library_versions(),
    })
    return out_dir


def load(path: str | os.PathLike) -> Critic:
    """Load a critic directory written by `train_critic`; refuses a missing or corrupt one with one line."""
    path = str(path)
    config = read_artifact_config(path, kind="critic", config_file=CONFIG_FILE, weights_file=WEIGHTS_FILE, fmt=CRITIC_FORMAT,
                                  hint="train one with `elegant train-critic`")
    config_path, weights_path = os.path.join(path, CONFIG_FILE), os.path.join(path, WEIGHTS_FILE)
    try:
        network = TwinQNetwork(**config["network"])
        encoder = TaskFeatureEncoder.from_dict(config["encoder"])
        normalization = Normalization.from_dict(config["normalization"])
    except (KeyError, TypeError, ValueError) as exc:
        raise UserInputError(f"{config_path}: missing or malformed field ({exc.__class__.__name__}: {exc})") from None
    try:
        state = torch.load(weights_path, map_location="cpu", weights_only=True)
        network.load_state_dict(state)
    except Exception as exc:  # torch raises many types for truncated/garbled files and mismatched shapes
        raise UserInputError(f"{weights_path}: corrupt or incompatible critic weights ({exc.__class__.__name__})") from None
    return Critic(network, encoder, normalization, config, path)
