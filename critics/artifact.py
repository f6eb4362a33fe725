"""The trained critic on disk and at run time.

A critic directory holds `critic.pt` (the `TwinQNetwork` state_dict) and `critic.json` (how to rebuild
and feed it: network config, the state encoding (`annotations.features`), observation normalisation, per-step
action bounds, the chunk length of the actions it scores, gamma, the training config and the library
versions). `load(dir)` returns a `Critic`, which
scores actions with the module's plain tensors under `torch.inference_mode`, without TensorDicts,
because JITI calls it inside the control loop (target: <= 150 us for one state and 16 actions on one
thread).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np
import torch
from threadpoolctl import ThreadpoolController

from annotations import FeatureEncoder, GoalContext, encoder_from_dict
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import atomic_write_json, library_versions, read_artifact_config
from base_suites.runtime.training import atomic_torch_save
from base_suites.stack import cpu_record
from critics.networks import TwinQNetwork
from critics.normalization import Normalization, clip_normalised_

CRITIC_FORMAT = "libero-elegant/critic/1"
WEIGHTS_FILE = "critic.pt"
CONFIG_FILE = "critic.json"


@dataclass(frozen=True)
class _Binding:
    """One task's observation encoding folded into the critics' first layer.

    The encoding of a state x of the task puts x into the first `state_size` columns and fixed values
    after them (padding, the task one-hot); normalisation shifts, scales and clips each column. So the
    first layer's state part is clip((x - mean) / std) @ W[:state_size] + (bias + t @ W[state_size:]),
    with t the normalised fixed columns: `q` needs one small normalise-and-clip and one small matmul.
    Both critics' columns sit side by side (critic c in columns c*H:(c+1)*H), so that matmul serves the
    pair. The goal-relative encoding is no such affine map: its binding keeps the episode's `context`,
    `q` encodes the state first, and the columns are the whole encoding (the binary ones unscaled).
    """

    task: str
    state_size: int
    state_mean: np.ndarray  # (columns,)
    state_inv_std: np.ndarray  # (columns,)
    state_weight: np.ndarray  # (columns, C * H)
    state_bias: np.ndarray  # (C * H,)
    context: GoalContext | None = None  # the goal-relative encoding's episode plan


def _blas_operand(tensor: torch.Tensor) -> np.ndarray:
    """A float32 weight in C order. For a decision's (16, 256) @ (256, 256) on one thread, OpenBLAS took
    27 us with C-ordered weights on both machines measured, while Fortran order ranged from 21 us on one
    to 51 us on the other (SkylakeX): C is the order without a bad case. The order is fixed rather than
    timed at start-up because the two orders' kernels may round differently (gemv shapes do), and the
    same seed must give the same Q values."""
    return np.ascontiguousarray(tensor.detach().numpy().astype(np.float32))


def _side_by_side(stacked: torch.Tensor) -> torch.Tensor:
    """(C, rows, H) per-critic weights -> (rows, C * H): critic c's columns at c*H:(c+1)*H."""
    c, rows, width = stacked.shape
    return stacked.permute(1, 0, 2).reshape(rows, c * width)


@dataclass(frozen=True)
class _TwinLayers:
    """The twin Q networks' layers after the state part, as NumPy arrays.

    The first layer's action part is one matmul for both critics (columns side by side, as in
    `_Binding`). The hidden layers are stacked per critic (a block-diagonal matmul would double their
    FLOPs): one `np.matmul` over a (C, rows, H) view runs each critic's gemm on its columns in place, as
    separate calls on the slices would, with a third of the NumPy calls.
    """

    width: int  # H, each critic's first hidden width
    action_weight: np.ndarray  # (A, C * H)
    hidden: list[tuple[np.ndarray, np.ndarray]]  # per later layer: (weights (C, H, H'), biases (C, 1, H'))
    last_rows: list[np.ndarray]  # per critic (H_last,)
    last_biases: list[np.float32]

    def q(self, first_layer: np.ndarray, scaled_actions: np.ndarray) -> np.ndarray:
        """min over critics of Q for B states x K actions: first_layer (B, C * H) is the state part with
        its bias, scaled_actions (B, K, A) in [-1, 1]. Returns (B * K,)."""
        batch, k, a = scaled_actions.shape
        h = (scaled_actions.reshape(batch * k, a) @ self.action_weight).reshape(batch, k, -1)
        h += first_layer[:, None, :]
        np.maximum(h, 0.0, out=h)
        h = h.reshape(batch * k, len(self.last_rows), self.width).transpose(1, 0, 2)  # (C, rows, H), a view
        for weight, bias in self.hidden:
            h = np.matmul(h, weight)
            h += bias
            np.maximum(h, 0.0, out=h)
        q = h[0] @ self.last_rows[0]
        q += self.last_biases[0]
        for c in range(1, len(self.last_rows)):
            q_c = h[c] @ self.last_rows[c]
            q_c += self.last_biases[c]
            np.minimum(q, q_c, out=q)
        return q


class _OneBlasThread:
    """Context: NumPy's BLAS on one thread inside, its previous thread counts restored on exit.

    With the CPU busy (the simulator, other jobs), OpenBLAS's worker threads wait for cores and a
    16-action decision took 5.8 ms instead of 0.5 ms (benchmarks/jiti_overhead.py). This talks to the
    BLAS libraries threadpoolctl found once, at construction, and costs ~4 us per use, against ~40 us for
    `threadpool_limits`, which looks the libraries up again on every entry.
    """

    def __init__(self) -> None:
        self._libraries = ThreadpoolController().select(user_api="blas").lib_controllers
        self._previous: list[int] = []

    def __enter__(self) -> None:
        self._previous = [library.get_num_threads() for library in self._libraries]
        for library, threads in zip(self._libraries, self._previous):
            if threads != 1:
                library.set_num_threads(1)

    def __exit__(self, *exc: object) -> None:
        for library, threads in zip(self._libraries, self._previous):
            if threads != 1:
                library.set_num_threads(threads)


class Critic:
    """An elegance critic: Q(s, a) = min over the twin critics, for states of the task it is bound to.

    `q` evaluates the saved `TwinQNetwork` in NumPy with its weights rearranged once at construction
    (per critic, in C order, the task encoding folded in at `bind`), because JITI calls it
    every step: the same numbers as `network(obs, actions)` on encoded, normalised inputs, in about half
    the time of the equivalent torch ops at this size (1 state x 16 actions, one thread).
    """

    def __init__(
        self,
        network: TwinQNetwork,
        encoder: FeatureEncoder,
        normalization: Normalization,
        config: Mapping[str, Any] | None = None,
        path: str = "critic",
    ) -> None:
        self.network = network.eval().requires_grad_(False)
        self.encoder = encoder
        self.normalization = normalization
        self.config = dict(config or {})
        self.path = path
        self.chunk = int(self.config.get("chunk", 1))  # critics written before action chunking score single actions
        # a chunk's actions are normalised step by step with the per-step bounds
        self._center = np.tile(normalization.action_center, self.chunk).astype(np.float32)
        self._inv_half = np.tile(1.0 / normalization.action_half_range, self.chunk).astype(np.float32)
        weights, biases = list(network.weights), list(network.biases)
        critics = range(network.n_critics)
        self._layers = _TwinLayers(
            width=network.action_weight.shape[-1],
            action_weight=_blas_operand(_side_by_side(network.action_weight)),
            hidden=[
                (_blas_operand(w), b.detach().numpy().astype(np.float32)) for w, b in zip(weights[:-1], biases[:-1])
            ],
            last_rows=[weights[-1][c, :, 0].detach().numpy().astype(np.float32) for c in critics],
            last_biases=[np.float32(biases[-1][c, 0, 0].item()) for c in critics],
        )
        self._binding: _Binding | None = None
        self._one_blas_thread = _OneBlasThread()
        self.device = torch.device("cpu")

    @property
    def tasks(self) -> list[str]:
        return list(self.encoder.tasks)

    @cached_property
    def _goal_columns(self) -> _Binding:
        """A goal-relative binding without its episode: every encoded column, the binary ones unscaled."""
        binary = self.encoder.dim - self.encoder.state_dim
        return _Binding(
            "",
            0,
            np.concatenate([self.normalization.obs_mean, np.zeros(binary, dtype=np.float32)]),
            np.concatenate([1.0 / self.normalization.obs_std, np.ones(binary, dtype=np.float32)]).astype(np.float32),
            _blas_operand(_side_by_side(self.network.obs_weight.detach())),
            self.network.first_bias.detach()[:, 0, :].reshape(-1).numpy().astype(np.float32),
        )

    @property
    def context(self) -> GoalContext | None:
        """The bound episode's goal-relative plan (None: unbound, or a task one-hot)."""
        return None if self._binding is None else self._binding.context

    def _binding_for(self, metadata: Mapping[str, Any], context: GoalContext | None = None) -> _Binding:
        context = self.encoder.check_env(metadata, self.path) if context is None else context
        if isinstance(context, GoalContext):  # the columns do not depend on the episode: built once
            return replace(self._goal_columns, task=context.task, state_size=context.state_size, context=context)
        key = context
        size = sum(s for _, s in self.encoder.layouts[key])
        fixed = torch.from_numpy(
            self.normalization.observations(self.encoder.encode(np.zeros(size, dtype=np.float32), key))
        )[size:]
        obs_weight = self.network.obs_weight.detach()  # (C, D, H)
        bias = self.network.first_bias.detach()[:, 0, :] + torch.einsum("d,cdh->ch", fixed, obs_weight[:, size:, :])
        return _Binding(
            key,
            size,
            self.normalization.obs_mean[:size].copy(),
            (1.0 / self.normalization.obs_std[:size]).astype(np.float32),
            _blas_operand(_side_by_side(obs_weight[:, :size, :])),
            bias.reshape(-1).numpy().astype(np.float32),
        )

    def bind(self, metadata: Mapping[str, Any], context: GoalContext | None = None) -> Critic:
        """Score states of the env described by `metadata` (suite, task_index, state_layout; goal_geometry
        for the goal-relative encoding, which changes per episode: JITI binds at every reset) from now on.

        Refuses (UserInputError) a task the critic cannot encode: one it was not trained on or a different
        observation layout (task one-hot), or one the goal-relative encoding cannot read. `context`: a
        goal-relative plan another critic made of the same `metadata` (an ensemble's members share it).
        """
        self._binding = self._binding_for(metadata, context)
        return self

    def q(self, state: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Q of raw env actions: state (D,) with actions (N, A) -> (N,); states (B, D) with (B, N, A) -> (B, N).

        A is 7 for a per-step critic and 7 * chunk for a critic of action chunks (each row a chunk's
        actions one after the other, `critics.data.action_chunks`)."""
        if self._binding is None:
            raise RuntimeError("Critic.q needs a task: call critic.bind(env.metadata) first")
        return self._score(self._binding, state, actions)

    def to(self, device: str | torch.device) -> Critic:
        """Score on `device` from now on. The CPU (the default) runs the NumPy path above; a GPU runs the
        network's torch forward on the encoded, normalised inputs, which agrees with it to rounding."""
        self.device = torch.device(device)
        self.network.to(self.device)
        return self

    def _score(self, b: _Binding, state: np.ndarray, actions: np.ndarray) -> np.ndarray:
        state = np.asarray(state, dtype=np.float32)
        actions = np.asarray(actions, dtype=np.float32)
        single = state.ndim == 1
        if single:
            state, actions = state[None], actions[None]
        width = len(self._center)
        if (
            state.ndim != 2
            or state.shape[1] != b.state_size
            or actions.ndim != 3
            or actions.shape[0] != state.shape[0]
            or actions.shape[2] != width
        ):
            raise UserInputError(
                f"{self.path}: Critic.q expects state ({b.state_size},) with actions (N, {width}) or states (B, "
                f"{b.state_size}) "
                f"with actions (B, N, {width}) for task {b.task} (chunks of {self.chunk} actions); got {state.shape} "
                f"and {actions.shape}"
            )
        # one finite sum stands for every entry being finite (a NaN or an infinity anywhere makes it not)
        if not math.isfinite(state.sum(dtype=np.float64) + actions.sum(dtype=np.float64)):
            raise UserInputError(f"{self.path}: Critic.q got a state or action holding NaN or infinity")
        scaled = (actions - self._center) * self._inv_half
        np.minimum(np.maximum(scaled, -1.0, out=scaled), 1.0, out=scaled)  # np.clip costs 3x as much here
        q = self._on_device(b, state, scaled) if self.device.type != "cpu" else self._on_cpu(b, state, scaled)
        q = q.reshape(actions.shape[:2])
        return q[0] if single else q

    def _on_cpu(self, b: _Binding, state: np.ndarray, scaled: np.ndarray) -> np.ndarray:
        if b.context is not None:
            state = self.encoder.encode(state, b.context)
        z = clip_normalised_((state - b.state_mean) * b.state_inv_std)  # as `Normalization.observations`
        with self._one_blas_thread:
            first_layer = z @ b.state_weight
            first_layer += b.state_bias
            return self._layers.q(first_layer, scaled)

    def _on_device(self, b: _Binding, state: np.ndarray, scaled: np.ndarray) -> np.ndarray:
        obs = self.normalization.observations(self.encoder.encode(state, b.task if b.context is None else b.context))
        with torch.inference_mode():
            q = self.network(torch.from_numpy(obs).to(self.device), torch.from_numpy(scaled).to(self.device))
            return q.min(0).values.cpu().numpy()


def save_critic(
    out_dir: str,
    network: TwinQNetwork,
    encoder: FeatureEncoder,
    normalization: Normalization,
    *,
    gamma: float,
    training: Mapping[str, Any],
    chunk: int = 1,
) -> str:
    """Write critic.pt and critic.json into out_dir (each atomically; the weights first)."""
    os.makedirs(out_dir, exist_ok=True)
    atomic_torch_save(
        os.path.join(out_dir, WEIGHTS_FILE), {k: v.detach().clone() for k, v in network.state_dict().items()}
    )
    atomic_write_json(
        os.path.join(out_dir, CONFIG_FILE),
        {
            "format": CRITIC_FORMAT,
            "network": network.config(),
            "encoder": encoder.to_dict(),
            "normalization": normalization.to_dict(),
            "gamma": float(gamma),
            "chunk": int(chunk),
            "training": dict(training),
            "versions": library_versions(),
            "machine": cpu_record(),  # trained weights depend on the CPU's float kernels
        },
    )
    return out_dir


def load(path: str | os.PathLike) -> Critic:
    """Load a critic directory written by `train_critic`; refuses a missing or corrupt one with one line."""
    path = str(path)
    config = read_artifact_config(
        path,
        kind="critic",
        config_file=CONFIG_FILE,
        weights_file=WEIGHTS_FILE,
        fmt=CRITIC_FORMAT,
        hint="train one with `elegant train-critic`",
    )
    config_path, weights_path = os.path.join(path, CONFIG_FILE), os.path.join(path, WEIGHTS_FILE)
    try:
        network = TwinQNetwork(**config["network"])
        encoder = encoder_from_dict(config["encoder"])
        normalization = Normalization.from_dict(config["normalization"])
    except (KeyError, TypeError, ValueError) as exc:
        raise UserInputError(f"{config_path}: missing or malformed field ({exc.__class__.__name__}: {exc})") from None
    chunk = config.get("chunk", 1)
    if network.action_dim != len(normalization.action_center) * chunk:
        raise UserInputError(
            f"{config_path}: network.action_dim {network.action_dim} is not the action size "
            f"{len(normalization.action_center)} x chunk {chunk}"
        )
    try:
        state = torch.load(weights_path, map_location="cpu", weights_only=True)
        network.load_state_dict(state)
    except Exception as exc:  # torch raises many types for truncated/garbled files and mismatched shapes
        raise UserInputError(
            f"{weights_path}: corrupt or incompatible critic weights ({exc.__class__.__name__})"
        ) from None
    return Critic(network, encoder, normalization, config, path)
