"""The BC policy network: an MLP trunk and a Gaussian-mixture action head, as in LIBERO's BC baselines.

A mixture head matters here for two reasons: demonstrations are multi-modal (go left or right around a
distractor), which a single Gaussian averages into a collision; and JITI needs the policy's own
distribution to draw candidate actions from. Means are tanh-squashed into the action bounds; standard
deviations are softplus plus a floor, so the likelihood cannot collapse onto a single demo point.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from elegant.policies.bc_config import DEFAULT_MODES
from elegant.policies.protocol import ACTION_DIM

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


class GMMHead(nn.Module):
    """Maps trunk features to mixture logits (B, K), means (B, K, A) in (-1, 1) and stds (B, K, A)."""

    def __init__(
        self, in_dim: int, *, action_dim: int = ACTION_DIM, modes: int = DEFAULT_MODES, min_std: float = 1e-4
    ) -> None:
        super().__init__()
        self.action_dim, self.modes, self.min_std = action_dim, modes, float(min_std)
        self.logits = nn.Linear(in_dim, modes)
        self.means = nn.Linear(in_dim, modes * action_dim)
        self.stds = nn.Linear(in_dim, modes * action_dim)

    def forward(self, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        shape = h.shape[:-1] + (self.modes, self.action_dim)
        means = torch.tanh(self.means(h)).view(shape)
        stds = (nn.functional.softplus(self.stds(h)) + self.min_std).view(shape)
        return self.logits(h), means, stds


def gmm_nll(logits: torch.Tensor, means: torch.Tensor, stds: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
    """Negative log-likelihood (B,) of actions (B, A) under the mixture."""
    z = (actions.unsqueeze(-2) - means) / stds
    component = -(0.5 * z.square() + stds.log() + _LOG_SQRT_2PI).sum(-1)
    return -torch.logsumexp(torch.log_softmax(logits, -1) + component, -1)


def gmm_mode(logits: torch.Tensor, means: torch.Tensor) -> torch.Tensor:
    """The mean (B, A) of each row's most likely component: the deterministic evaluation action."""
    best = logits.argmax(-1)
    return means[torch.arange(means.shape[0]), best]


def gmm_draw_components(logits: torch.Tensor, n: int, generator: torch.Generator) -> torch.Tensor:
    """n component indices (n,) drawn by the mixture weights of a single row (logits (1, K))."""
    return torch.multinomial(torch.softmax(logits[0], -1), n, replacement=True, generator=generator)


def gmm_component_means(logits: torch.Tensor, means: torch.Tensor, n: int, generator: torch.Generator) -> torch.Tensor:
    """The means (n, A) of n components drawn by weight from a single row: a draw without the Gaussian
    noise, what LIBERO executes with its GMM head's `low_eval_noise` (scales set to ~0 at evaluation)."""
    return means[0, gmm_draw_components(logits, n, generator)]


def gmm_sample(
    logits: torch.Tensor, means: torch.Tensor, stds: torch.Tensor, n: int, generator: torch.Generator
) -> torch.Tensor:
    """Draw n actions (n, A) from the mixture of a single row (logits (1, K)), clipped to [-1, 1]."""
    component = gmm_draw_components(logits, n, generator)
    noise = torch.randn((n, means.shape[-1]), generator=generator, dtype=means.dtype, device=means.device)
    return (means[0, component] + stds[0, component] * noise).clamp(-1.0, 1.0)


class BCNet(nn.Module):
    """MLP trunk (ReLU) over the flattened history window plus task one-hot, then the GMM head.

    With `task_dim` > 0 the last `task_dim` inputs (the task one-hot) also modulate every hidden layer
    (FiLM: h * (1 + gamma(task)) + beta(task), before the ReLU), as LIBERO's baselines condition on the
    instruction. In libero_goal all ten tasks share one scene, so the one-hot is the only input that says
    which task to do; entering at the input alone, it is 10 of ~800 numbers and the policy mixes tasks up.
    The FiLM layers start at zero, so training starts from the plain MLP."""

    def __init__(
        self,
        input_dim: int,
        *,
        hidden: Sequence[int] = (256, 256),
        action_dim: int = ACTION_DIM,
        modes: int = DEFAULT_MODES,
        min_std: float = 1e-4,
        task_dim: int = 0,
    ) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        width = input_dim
        for size in hidden:
            layers += [nn.Linear(width, size), nn.ReLU()]
            width = size
        self.trunk = nn.Sequential(*layers)
        self.task_dim = int(task_dim)
        self.film = nn.ModuleList(nn.Linear(self.task_dim, 2 * size) for size in hidden) if self.task_dim else None
        if self.film is not None:
            for layer in self.film:
                nn.init.zeros_(layer.weight)
                nn.init.zeros_(layer.bias)
        self.head = GMMHead(width, action_dim=action_dim, modes=modes, min_std=min_std)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        if self.film is None:
            return self.head(self.trunk(x))
        task, h = x[..., -self.task_dim :], x
        for linear, film in zip(self.trunk[0::2], self.film):
            gamma, beta = film(task).chunk(2, dim=-1)
            h = torch.relu(linear(h) * (1.0 + gamma) + beta)
        return self.head(h)

    def nll(self, x: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        return gmm_nll(*self(x), actions)
