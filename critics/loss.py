"""Cal-QL as a TorchRL `LossModule`: CQL with twin critics, a SAC actor, and Monte-Carlo calibration.

Why not `torchrl.objectives.CQLLoss`: it scores the actions drawn from pi(.|s') at s' and takes its
logsumexp over the wrong axis (3 values per sample instead of the 3N sampled actions of each state).
Here, as in the CQL and Cal-QL references, every sampled action is scored at s:

    ood(s) = T * logsumexp_j [(Q(s, a_j) - log rho(a_j)) / T]   over the 3N actions of state s:
             N uniform on [-1, 1]^A (log rho = A log 0.5), N from pi(.|s) and N from pi(.|s')
             (log rho = their log-probs under pi);
    loss_cql = cql_weight * sum over critics of mean_s [ood(s) - Q(s, a_data)].

Cal-QL's calibration: before the logsumexp, the Q values of the policy-drawn actions are clipped from
below by the Monte-Carlo return of the dataset trajectory (`mc_return`), so the CQL push-down never
drives Q of a policy action below the return the data actually achieved from s.

The TD target r + gamma * min_c Q_target(s', a') takes a' ~ pi(.|s') as Cal-QL does (`backup="policy"`),
or the dataset's next action (`backup="dataset"`, in-sample as in SARSA and IQL), which keeps the
actor's pushed-down actions out of the backup.

`value_loss="bce"` (for returns in [0, 1], the elegant-success reward): the critics output logits, the TD
target is r + gamma^k * sigmoid(min target logit(s', a')), a probability, and each critic is fitted to it
by binary cross-entropy, as classification value losses do (Farebrother et al. 2024, "Stop Regressing");
the CQL term and Cal-QL's floor (the logit of the MC return) act on the logits. Why: squared error on a
rare binary outcome ranked a policy's candidates worse than cross-entropy on the same data and network.

`mc_weight` > 0 adds to the TD regression a regression of Q(s, a_data) on the Monte-Carlo return itself
(where it is one, not the "no floor" mark): TD(0) through chunk after chunk barely carried an outcome 100
steps away back to the decision that caused it, while the same network fitted to the returns ranked a
policy's candidates by their simulated outcomes (`elegant rank-check`).

Each `loss_*` term sends gradients only to its own parameters (the critic terms to the critics, the actor
term to the actor through its reparameterised action, the temperature terms to their log-multipliers), so
their sum can be back-propagated once and stepped with one optimiser. The input tensordict is not
modified. Returns-to-go are not computed here: they are a data transform (`critics.data`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase, TensorDictParams
from tensordict.utils import NestedKey
from torch import Tensor
from torchrl.objectives import LossModule
from torchrl.objectives.value.functional import td0_return_estimate

from critics.config import BACKUPS, VALUE_LOSSES, TrainConfig
from critics.data import NO_FLOOR
from critics.networks import TanhGaussianActor, TwinQNetwork

LOGIT_LIMIT = 10.0  # the logit floor of a certain outcome (sigmoid(10) = 0.99995)


def cql_logsumexp(
    q_uniform: Tensor,
    q_policy: Tensor,
    policy_log_prob: Tensor,
    mc_return: Tensor | None,
    *,
    action_dim: int,
    temperature: float = 1.0,
) -> Tensor:
    """Importance-sampled soft maximum of Q over each state's sampled actions.

    q_uniform (C, B, N): Q of N actions uniform on [-1, 1]^action_dim at B states, for C critics;
    q_policy (C, B, M): Q of M policy-drawn actions at the same states, policy_log_prob (B, M) their
    log-densities; mc_return (B,): Cal-QL's floor for q_policy (None: plain CQL, no floor).
    Returns (C, B): temperature * logsumexp over the N + M actions of each state of (Q - log density) / T.
    """
    if mc_return is not None:
        q_policy = torch.maximum(q_policy, mc_return.unsqueeze(-1))
    uniform_log_density = action_dim * math.log(0.5)
    scores = torch.cat([q_uniform - uniform_log_density, q_policy - policy_log_prob], dim=-1)
    return temperature * torch.logsumexp(scores / temperature, dim=-1)


@dataclass
class CalQLTerms:
    """What one forward pass computes once and the loss terms share (returned by `CalQLLoss.terms`).

    The TD target backs up min over target critics of Q(s', a'), without an entropy bonus, as in
    Cal-QL's reference implementation; a' ~ pi(.|s') there, or the dataset's next action (`backup`).
    """

    actor_log_prob: Tensor  # (B,) log pi(a~|s), differentiable w.r.t. the actor
    actor_q: Tensor  # (B,) min over critics of Q(s, a~), critic parameters detached
    q_data: Tensor  # (C, B) Q(s, a_data)
    q_uniform: Tensor  # (C, B, N)
    q_policy: Tensor  # (C, B, 2N) actions from pi(.|s) then pi(.|s'), all scored at s
    policy_log_prob: Tensor  # (B, 2N), detached
    target: Tensor  # (B,) r + gamma^steps (1 - terminated) min over target critics of Q(s', a')
    mc_return: Tensor  # (B,)


class CalQLLoss(LossModule):
    """Calibrated Conservative Q-Learning (Nakamoto et al. 2023) for offline training of an elegance critic.

    Args:
        actor_network: the tanh-Gaussian SAC actor (`critics.networks.TanhGaussianActor`).
        qvalue_network: the stacked twin critic (`critics.networks.TwinQNetwork`); its target copy is
            kept in `target_qvalue_network_params`, to be updated by `torchrl.objectives.SoftUpdate`.

    Keyword Args:
        gamma: discount of the TD backup; must be the one the `mc_return` entries were computed with.
        n_actions: N, the number of uniform, pi(.|s) and pi(.|s') actions per state (3N in all).
        cql_weight: the CQL regulariser's weight (alpha in CQL's paper).
        temperature: the logsumexp temperature T.
        calibrate: clip Q of policy actions from below by `mc_return` (Cal-QL); False gives plain CQL.
        with_lagrange: tune the CQL weight automatically (multiplier exp(log_alpha_prime)) so that the
            mean gap ood(s) - Q(s, a_data) approaches `target_action_gap`.
        target_action_gap: the Lagrange target (only with `with_lagrange`).
        alpha_init: the initial SAC entropy temperature.
        fixed_alpha: keep the entropy temperature at alpha_init instead of tuning it.
        target_entropy: the entropy the temperature tuning aims at; "auto" is -action_dim.
        backup: the next action a' of the TD target. "policy": a' ~ pi(.|s'), Cal-QL's. "dataset": the
            dataset's next action (read under ("next", action)), an in-sample backup as in SARSA and IQL;
            Q then values the demonstrator's continuation (`TrainConfig.backup` says which the recipe takes).
        mc_weight: weight of the regression of Q(s, a_data) on `mc_return` added to loss_qvalue (rows
            whose return is `critics.data.NO_FLOOR` are left out); 0 is Cal-QL's TD alone.
        value_loss: "mse" or "bce" (logit critics classified against target probabilities; rewards and
            returns must lie in [0, 1]).

    The settings `TrainConfig` declares have no defaults here: `from_config` passes the recipe's, and a
    caller building the loss by hand says every one (one declaration per setting, docs/design.md §9).

    Reads (names configurable with `set_keys`): observation, action, mc_return, ("next", observation),
    ("next", reward), ("next", terminated), and steps_to_next_obs where present (multi-step and action-chunk
    transitions: the bootstrap is discounted by gamma ** steps_to_next_obs, TorchRL's value-estimator
    convention). Rewards, terminated flags, returns and step counts may be (B,) or (B, 1).
    """

    @dataclass
    class _AcceptedKeys:
        """The tensordict keys the loss reads; change them with `loss.set_keys(name=key)`.

        Attributes:
            observation: the encoded, normalised state; also read under "next" for s'. Default "observation".
            action: the dataset action, normalised to [-1, 1]. Default "action".
            reward: the elegance reward, read under "next". Default "reward".
            terminated: True where the episode ended in a terminal state (no bootstrap), read under
                "next". Default "terminated".
            mc_return: the discounted return-to-go of the dataset trajectory (Cal-QL's floor). Default "mc_return".
            steps_to_next_obs: how many env steps separate s and s' (optional; absent means 1). Default
                "steps_to_next_obs" (as written by `torchrl.data.postprocs.MultiStep`).
        """

        observation: NestedKey = "observation"
        action: NestedKey = "action"
        reward: NestedKey = "reward"
        terminated: NestedKey = "terminated"
        mc_return: NestedKey = "mc_return"
        steps_to_next_obs: NestedKey = "steps_to_next_obs"

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys

    actor_network: TanhGaussianActor
    qvalue_network: TwinQNetwork
    actor_network_params: TensorDictParams
    qvalue_network_params: TensorDictParams
    target_actor_network_params: TensorDictParams
    target_qvalue_network_params: TensorDictParams

    def __init__(
        self,
        actor_network: TanhGaussianActor,
        qvalue_network: TwinQNetwork,
        *,
        gamma: float,
        n_actions: int,
        cql_weight: float,
        temperature: float,
        calibrate: bool,
        with_lagrange: bool,
        target_action_gap: float,
        backup: str,
        mc_weight: float,
        value_loss: str,
        alpha_init: float = 1.0,
        fixed_alpha: bool = False,
        target_entropy: float | str = "auto",
    ) -> None:
        super().__init__()
        if value_loss not in VALUE_LOSSES:
            raise ValueError(f"value_loss must be one of {', '.join(VALUE_LOSSES)}, got {value_loss!r}")
        if backup not in BACKUPS:
            raise ValueError(f"backup must be one of {', '.join(BACKUPS)}, got {backup!r}")
        if actor_network.action_dim != qvalue_network.action_dim or actor_network.obs_dim != qvalue_network.obs_dim:
            raise ValueError("actor and critic disagree on observation or action size")
        self.convert_to_functional(actor_network, "actor_network")
        self.convert_to_functional(qvalue_network, "qvalue_network", create_target_params=True)
        self.action_dim = qvalue_network.action_dim
        self.gamma = float(gamma)
        self.n_actions = int(n_actions)
        self.cql_weight = float(cql_weight)
        self.temperature = float(temperature)
        self.calibrate = bool(calibrate)
        self.with_lagrange = bool(with_lagrange)
        self.target_action_gap = float(target_action_gap)
        self.target_entropy = -float(self.action_dim) if target_entropy == "auto" else float(target_entropy)
        self.backup = backup
        self.mc_weight = float(mc_weight)
        self.value_loss = value_loss
        log_alpha = torch.tensor(math.log(alpha_init))
        if fixed_alpha:
            self.register_buffer("log_alpha", log_alpha)
        else:
            self.log_alpha = torch.nn.Parameter(log_alpha)
        if self.with_lagrange:
            self.log_alpha_prime = torch.nn.Parameter(torch.tensor(0.0))

    @classmethod
    def from_config(
        cls, actor_network: TanhGaussianActor, qvalue_network: TwinQNetwork, config: TrainConfig, gamma: float
    ) -> CalQLLoss:
        """The loss a `TrainConfig` describes; `gamma` is the data's (the config's, or the annotation's
        where the config leaves it None: `TransitionData.gamma`)."""
        return cls(
            actor_network,
            qvalue_network,
            gamma=gamma,
            n_actions=config.n_actions,
            cql_weight=config.cql_weight,
            temperature=config.temperature,
            calibrate=config.calibrate,
            with_lagrange=config.with_lagrange,
            target_action_gap=config.target_action_gap,
            backup=config.backup,
            mc_weight=config.mc_weight,
            value_loss=config.value_loss,
        )

    # ---- keys --------------------------------------------------------------------------------
    @property
    def in_keys(self) -> list[NestedKey]:
        k = self.tensor_keys
        keys = [
            k.observation,
            k.action,
            k.mc_return,
            ("next", k.observation),
            ("next", k.reward),
            ("next", k.terminated),
        ]
        return keys + ([("next", k.action)] if self.backup == "dataset" else [])

    @property
    def out_keys(self) -> list[str]:
        keys = ["loss_actor", "loss_qvalue", "loss_cql", "loss_alpha"]
        diagnostics = ["alpha", "entropy", "q_data", "td_target", "cql_gap", "calibrated_fraction"]
        if self.with_lagrange:
            keys.append("loss_alpha_prime")
            diagnostics.append("alpha_prime")
        return keys + diagnostics

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        """No value estimator: the TD(0) target is computed directly with `td0_return_estimate`."""

    # ---- the shared pass ---------------------------------------------------------------------
    @property
    def alpha(self) -> Tensor:
        return self.log_alpha.detach().exp()

    @property
    def alpha_prime(self) -> Tensor:
        return self.log_alpha_prime.detach().exp().clamp(max=1e6) if self.with_lagrange else torch.ones(())

    def _q(self, params: TensorDictBase, obs: Tensor, actions: Tensor) -> Tensor:
        with params.to_module(self.qvalue_network):
            return self.qvalue_network(obs, actions)

    def terms(self, tensordict: TensorDictBase) -> CalQLTerms:
        """Run the actor once on s and s' and the critics once on all 1 + 3N actions of each state."""
        k = self.tensor_keys
        obs = tensordict.get(k.observation)
        next_obs = tensordict.get(("next", k.observation))
        action = tensordict.get(k.action)
        batch = action.shape[0]
        reward = tensordict.get(("next", k.reward)).reshape(batch)
        terminated = tensordict.get(("next", k.terminated)).reshape(batch)
        mc_return = tensordict.get(k.mc_return).reshape(batch).to(obs.dtype)
        steps = tensordict.get(k.steps_to_next_obs, None)
        gamma = self.gamma if steps is None else self.gamma ** steps.reshape(batch).to(obs.dtype)
        n = self.n_actions

        with self.actor_network_params.to_module(self.actor_network):
            dist = self.actor_network.distribution(torch.cat([obs, next_obs]))
        drawn, drawn_log_prob = dist.rsample_and_log_prob((n + 1,))  # (n+1, 2B, A), (n+1, 2B)
        actor_action, actor_log_prob = drawn[0, :batch], drawn_log_prob[0, :batch]
        next_action = tensordict.get(("next", k.action)) if self.backup == "dataset" else drawn[0, batch:].detach()
        policy_actions = drawn[1:].detach().view(n, 2, batch, -1).permute(2, 1, 0, 3).reshape(batch, 2 * n, -1)
        policy_log_prob = drawn_log_prob[1:].detach().view(n, 2, batch).permute(2, 1, 0).reshape(batch, 2 * n)

        uniform = torch.empty(batch, n, self.action_dim, dtype=action.dtype, device=action.device).uniform_(-1.0, 1.0)
        q = self._q(self.qvalue_network_params, obs, torch.cat([action.unsqueeze(1), uniform, policy_actions], dim=1))
        actor_q = self._q(self.qvalue_network_params.detach(), obs, actor_action.unsqueeze(1)).amin(0).squeeze(-1)
        with torch.no_grad():  # .data: swapping the target buffers into the module would turn them into Parameters
            next_value = (
                self._q(self.target_qvalue_network_params.data, next_obs, next_action.unsqueeze(1)).amin(0).squeeze(-1)
            )
            if self.value_loss == "bce":
                next_value = torch.sigmoid(next_value)
            target = td0_return_estimate(gamma, next_value, reward.to(next_value.dtype), terminated.bool())
        return CalQLTerms(
            actor_log_prob=actor_log_prob,
            actor_q=actor_q,
            q_data=q[:, :, 0],
            q_uniform=q[:, :, 1 : n + 1],
            q_policy=q[:, :, n + 1 :],
            policy_log_prob=policy_log_prob,
            target=target,
            mc_return=mc_return,
        )

    def _terms_of(self, tensordict: TensorDictBase, terms: CalQLTerms | None) -> CalQLTerms:
        return self.terms(tensordict) if terms is None else terms

    # ---- the loss terms ----------------------------------------------------------------------
    def qvalue_loss(self, tensordict: TensorDictBase, terms: CalQLTerms | None = None) -> tuple[Tensor, dict]:
        """TD(0) fit of every critic on dataset actions (`_fit`: squared error, or cross-entropy of logits with
        value_loss "bce"; mean over the batch, summed over critics), plus `mc_weight` times the same fit on
        the Monte-Carlo returns."""
        t = self._terms_of(tensordict, terms)
        loss = self._fit(t.q_data, t.target).mean(-1).sum(0)
        if self.mc_weight > 0:
            known = (t.mc_return > NO_FLOOR).to(t.q_data.dtype)
            mc_error = (self._fit(t.q_data, t.mc_return) * known).sum(-1) / known.sum().clamp(min=1.0)
            loss = loss + self.mc_weight * mc_error.sum(0)
        return loss, {"q_data": t.q_data.detach().mean(), "td_target": t.target.mean()}

    def _fit(self, q: Tensor, target: Tensor) -> Tensor:
        """(C, B) per-critic, per-row loss of outputs q against targets (B,)."""
        if self.value_loss == "bce":
            return torch.nn.functional.binary_cross_entropy_with_logits(
                q, target.clamp(0.0, 1.0).expand_as(q), reduction="none"
            )
        return (q - target).pow(2)

    def _floor(self, mc_return: Tensor) -> Tensor:
        """Cal-QL's floor in the critics' units: the MC return, or its logit for logit critics."""
        if self.value_loss == "bce":
            return torch.logit(mc_return.clamp(0.0, 1.0)).clamp(-LOGIT_LIMIT, LOGIT_LIMIT)
        return mc_return

    def _cql_gap(self, t: CalQLTerms) -> Tensor:
        """(C, B): ood(s) - Q(s, a_data) for each critic and state."""
        floor = self._floor(t.mc_return) if self.calibrate else None
        ood = cql_logsumexp(
            t.q_uniform, t.q_policy, t.policy_log_prob, floor, action_dim=self.action_dim, temperature=self.temperature
        )
        return ood - t.q_data

    def cql_loss(self, tensordict: TensorDictBase, terms: CalQLTerms | None = None) -> tuple[Tensor, dict]:
        """The conservative regulariser (weighted by the Lagrange multiplier, detached, when tuned)."""
        t = self._terms_of(tensordict, terms)
        gap = self._cql_gap(t).mean(-1)  # (C,)
        offset = self.target_action_gap if self.with_lagrange else 0.0
        loss = (self.cql_weight * self.alpha_prime * (gap - offset)).sum(0)
        calibrated = (t.q_policy.detach() < self._floor(t.mc_return).unsqueeze(-1)).float().mean()
        return loss, {"cql_gap": gap.detach().mean(), "calibrated_fraction": calibrated}

    def alpha_prime_loss(self, tensordict: TensorDictBase, terms: CalQLTerms | None = None) -> tuple[Tensor, dict]:
        """Lagrange dual step: raise the CQL weight while the gap exceeds target_action_gap."""
        if not self.with_lagrange:
            raise RuntimeError("alpha_prime_loss needs CalQLLoss(with_lagrange=True)")
        t = self._terms_of(tensordict, terms)
        gap = self._cql_gap(t).detach().mean(-1)
        alpha_prime = self.log_alpha_prime.exp().clamp(max=1e6)
        loss = -(alpha_prime * self.cql_weight * (gap - self.target_action_gap)).mean(0)
        return loss, {"alpha_prime": alpha_prime.detach()}

    def actor_loss(self, tensordict: TensorDictBase, terms: CalQLTerms | None = None) -> tuple[Tensor, dict]:
        """SAC's actor objective alpha * log pi(a~|s) - min_critics Q(s, a~) (critics frozen)."""
        t = self._terms_of(tensordict, terms)
        loss = (self.alpha * t.actor_log_prob - t.actor_q).mean()
        return loss, {"entropy": -t.actor_log_prob.detach().mean()}

    def alpha_loss(self, tensordict: TensorDictBase, terms: CalQLTerms | None = None) -> tuple[Tensor, dict]:
        """SAC's temperature objective: move the policy entropy towards target_entropy."""
        t = self._terms_of(tensordict, terms)
        loss = -(self.log_alpha * (t.actor_log_prob.detach() + self.target_entropy)).mean()
        return loss, {"alpha": self.alpha}

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        terms = self.terms(tensordict)
        out: dict[str, Tensor] = {}
        metadata: dict[str, Tensor] = {}
        for name, method in (
            ("loss_actor", self.actor_loss),
            ("loss_qvalue", self.qvalue_loss),
            ("loss_cql", self.cql_loss),
            ("loss_alpha", self.alpha_loss),
            *((("loss_alpha_prime", self.alpha_prime_loss),) if self.with_lagrange else ()),
        ):
            out[name], meta = method(tensordict, terms)
            metadata.update(meta)
        return TensorDict({**out, **metadata}, batch_size=[])
