"""The critic's and the actor's networks as plain `nn.Module`s.

The twin critic keeps both Q networks' weights stacked along a leading axis of size 2, so one batched
matmul per layer evaluates both (no vmap, no TensorDict). Its first layer is split into an observation
part and an action part: the observation part is computed once per state and shared by all the actions
scored at that state (a Cal-QL step scores 1 + 3N actions per state; a JITI decision 16). Together with
the fused backward below, this runs a Cal-QL step near this CPU's matmul roofline.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import torch
from torch import Tensor, nn
from torchrl.modules import MLP, NormalParamExtractor, TanhNormal


def _uniform_(tensor: Tensor, fan_in: int) -> Tensor:
    """nn.Linear's default initialisation: U(-1/sqrt(fan_in), 1/sqrt(fan_in)) for weights and biases."""
    bound = 1.0 / math.sqrt(fan_in)
    with torch.no_grad():
        return tensor.uniform_(-bound, bound)


# Rows (state-action pairs) per chunk of the fused training pass: large enough for efficient matmuls,
# small enough that a chunk's activations (2 critics x rows x 256 floats, ~1 MB) stay in cache.
_CHUNK_ROWS = 512


def _forward_rows(
    per_state: Tensor,
    actions: Tensor,
    k: int,
    action_weight: Tensor,
    weights: Sequence[Tensor],
    biases: Sequence[Tensor],
) -> tuple[Tensor, list[Tensor]]:
    """Q of S states x k actions each: per_state (C, S, H) is the states' first-layer part (bias included),
    actions (S * k, A). Returns q (C, S * k) and the post-ReLU activations of every hidden layer."""
    c, s, width = per_state.shape
    h = torch.baddbmm(
        per_state.repeat_interleave(k, dim=1), actions.expand(c, s * k, actions.shape[-1]), action_weight
    ).relu_()
    hidden = [h]
    for w, b in zip(weights[:-1], biases[:-1]):
        h = torch.baddbmm(b, h, w).relu_()
        hidden.append(h)
    # the last layer has one output: a broadcast multiply-sum is ~5x faster than a matmul with N = 1
    q = (h * weights[-1].transpose(1, 2)).sum(-1) + biases[-1].view(c, 1)
    return q, hidden


class _FusedTwinMLP(torch.autograd.Function):
    """Forward and hand-written backward of the twin MLP, chunk by chunk over states.

    Autograd's version materialises every intermediate of the (C, B * K, 256) activations in memory and
    runs the last layer's gradients as matmuls with a dimension of 1; here each chunk's backward runs on
    activations that are still in cache and the last layer uses elementwise ops. Used only when the
    parameters, and not the inputs, need gradients (the critic regression and CQL terms).
    """

    @staticmethod
    def forward(
        ctx,
        obs: Tensor,
        actions: Tensor,
        obs_weight: Tensor,
        action_weight: Tensor,
        first_bias: Tensor,
        *layers: Tensor,
    ) -> Tensor:
        n = len(layers) // 2
        weights, biases = layers[:n], layers[n:]
        batch, k, a = actions.shape
        c = obs_weight.shape[0]
        per_state = torch.baddbmm(first_bias, obs.expand(c, batch, obs.shape[-1]), obs_weight)
        flat = actions.reshape(batch * k, a)
        step = max(1, _CHUNK_ROWS // k)
        q = torch.empty(c, batch, k, dtype=obs.dtype, device=obs.device)
        ctx.hidden = []
        for s0 in range(0, batch, step):
            s1 = min(batch, s0 + step)
            q_rows, hidden = _forward_rows(
                per_state[:, s0:s1], flat[s0 * k : s1 * k], k, action_weight, weights, biases
            )
            q[:, s0:s1] = q_rows.view(c, s1 - s0, k)
            ctx.hidden.append(hidden)
        ctx.save_for_backward(obs, flat, obs_weight, action_weight, *layers)
        ctx.k, ctx.step = k, step
        return q

    @staticmethod
    def backward(ctx, dq: Tensor) -> tuple[Tensor | None, ...]:
        obs, flat, obs_weight, action_weight, *layers = ctx.saved_tensors
        n = len(layers) // 2
        weights = layers[:n]
        k, step = ctx.k, ctx.step
        c, batch = dq.shape[0], obs.shape[0]
        width = obs_weight.shape[-1]
        d_weights = [torch.zeros_like(w) for w in weights]
        d_biases = [torch.zeros_like(b) for b in layers[n:]]
        d_action_weight = torch.zeros_like(action_weight)
        d_per_state = torch.empty(c, batch, width, dtype=dq.dtype, device=dq.device)
        last_row = weights[-1].transpose(1, 2)  # (C, 1, H)
        transposed = [w.transpose(1, 2).contiguous() for w in weights[:-1]]
        for chunk, s0 in enumerate(range(0, batch, step)):
            s1 = min(batch, s0 + step)
            hidden = ctx.hidden[chunk]
            g = dq[:, s0:s1].reshape(c, (s1 - s0) * k, 1)
            d_weights[-1] += torch.bmm(g.transpose(1, 2), hidden[-1]).transpose(1, 2)
            d_biases[-1] += g.sum(1, keepdim=True)
            g = torch.ops.aten.threshold_backward(g * last_row, hidden[-1], 0)
            for i in range(n - 2, -1, -1):
                d_weights[i] += torch.bmm(hidden[i].transpose(1, 2), g)
                d_biases[i] += g.sum(1, keepdim=True)
                g = torch.ops.aten.threshold_backward(torch.bmm(g, transposed[i]), hidden[i], 0)
            d_action_weight += torch.matmul(flat[s0 * k : s1 * k].t(), g)
            torch.sum(g.view(c, s1 - s0, k, width), dim=2, out=d_per_state[:, s0:s1])
        del ctx.hidden
        d_obs_weight = torch.matmul(obs.t(), d_per_state)
        d_first_bias = d_per_state.sum(1, keepdim=True)
        return (None, None, d_obs_weight, d_action_weight, d_first_bias, *d_weights, *d_biases)


class TwinQNetwork(nn.Module):
    """`n_critics` Q(s, a) MLPs (ReLU) evaluated together; forward returns every critic's values.

    forward(obs (B, D), actions (B, K, A)) -> (n_critics, B, K): each state's K actions scored by each critic.
    When only the parameters need gradients (training the critics), the pass runs through a fused,
    chunked forward/backward; otherwise (inference, or gradients w.r.t. the actions) through autograd.
    """

    def __init__(self, obs_dim: int, action_dim: int, hidden: Sequence[int] = (256, 256), n_critics: int = 2) -> None:
        super().__init__()
        if not hidden:
            raise ValueError("TwinQNetwork needs at least one hidden layer")
        self.obs_dim, self.action_dim, self.hidden, self.n_critics = (
            int(obs_dim),
            int(action_dim),
            tuple(int(h) for h in hidden),
            int(n_critics),
        )
        fan_in = self.obs_dim + self.action_dim
        first = self.hidden[0]
        self.obs_weight = nn.Parameter(_uniform_(torch.empty(n_critics, obs_dim, first), fan_in))
        self.action_weight = nn.Parameter(_uniform_(torch.empty(n_critics, action_dim, first), fan_in))
        self.first_bias = nn.Parameter(_uniform_(torch.empty(n_critics, 1, first), fan_in))
        sizes = [*self.hidden, 1]
        self.weights = nn.ParameterList(
            nn.Parameter(_uniform_(torch.empty(n_critics, i, o), i)) for i, o in zip(sizes[:-1], sizes[1:])
        )
        self.biases = nn.ParameterList(
            nn.Parameter(_uniform_(torch.empty(n_critics, 1, o), i)) for i, o in zip(sizes[:-1], sizes[1:])
        )

    def forward(self, obs: Tensor, actions: Tensor) -> Tensor:
        params = (self.obs_weight, self.action_weight, self.first_bias, *self.weights, *self.biases)
        if (
            torch.is_grad_enabled()
            and not (obs.requires_grad or actions.requires_grad)
            and any(p.requires_grad for p in params)
        ):
            return _FusedTwinMLP.apply(obs, actions, *params)
        batch, k, a = actions.shape
        per_state = torch.baddbmm(self.first_bias, obs.expand(self.n_critics, batch, self.obs_dim), self.obs_weight)
        q, _ = _forward_rows(
            per_state, actions.reshape(batch * k, a), k, self.action_weight, list(self.weights), list(self.biases)
        )
        return q.view(self.n_critics, batch, k)

    def config(self) -> dict[str, Any]:
        """The constructor arguments, to rebuild the module from a saved state_dict."""
        return {
            "obs_dim": self.obs_dim,
            "action_dim": self.action_dim,
            "hidden": list(self.hidden),
            "n_critics": self.n_critics,
        }


class TanhGaussianActor(nn.Module):
    """SAC's actor: an MLP giving a Gaussian's location and scale, squashed by tanh into [-1, 1]^A."""

    def __init__(self, obs_dim: int, action_dim: int, hidden: Sequence[int] = (256, 256)) -> None:
        super().__init__()
        self.obs_dim, self.action_dim, self.hidden = int(obs_dim), int(action_dim), tuple(int(h) for h in hidden)
        self.net = MLP(
            in_features=obs_dim, out_features=2 * action_dim, num_cells=list(self.hidden), activation_class=nn.ReLU
        )
        self.loc_scale = NormalParamExtractor()

    def forward(self, obs: Tensor) -> tuple[Tensor, Tensor]:
        return self.loc_scale(self.net(obs))

    def distribution(self, obs: Tensor) -> TanhNormal:
        loc, scale = self(obs)
        return TanhNormal(loc, scale, low=-1.0, high=1.0)
