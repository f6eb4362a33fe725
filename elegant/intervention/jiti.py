"""JITI: just-in-time intervention of an elegance critic on a base policy (docs/design.md, JITI).

`JITI(policy, critic)` is a policy with the base policy's call signature. At each decision it scores the
base plan, q_t = Q(s_t, a_t), against the mean m_t of the last `window` scores; at a critical moment (the
trigger fires) it draws N candidates from the base policy itself, the base plan kept as candidate 0, and
executes the one the selector picks (the critic's argmax within the trust radius). Settings are one
`JITIConfig`; its mode is a registered object (`elegant.intervention.modes`) that builds the trigger and
the selector.

Contract, each for a reason:
- The window holds the score of what was executed (q_t, or the chosen candidate's), so after a correction
  the new level becomes the reference instead of triggering again.
- While the window fills no fluctuation can be measured: mode "jiti" executes the base plan there
  (warm-up "base") or re-ranks as "always" does (warm-up "steer"), since the start of an episode, where
  the policy commits to its approach and grasp, is a critical moment no fluctuation reveals.
- Ties and disagreement keep the base plan: JITI never overrides without a reason (`choose_candidate`).
- Action chunks: a `ChunkedPolicy` decides `chunk` actions at once; JITI then decides per chunk, with a
  critic trained on chunks of the same length, so one choice changes the next `chunk` steps coherently.
- Decision time excludes the base policy's own forward pass, which is paid without JITI too.
- The agent's settings never change during a run; an episode's inputs (its seed, and in mode "random"
  the steps it explores) arrive through `reset`.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Collection, Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any, Protocol

import numpy as np

from base_suites.runtime.errors import UserInputError
from base_suites.runtime.settings import with_overrides
from elegant.intervention.config import JITIConfig
from elegant.intervention.modes import check_policy, jiti_mode
from elegant.intervention.selectors import Choice
from elegant.intervention.triggers import Moment
from elegant.policies.adapters import as_policy
from elegant.policies.protocol import ACTION_DIM, ACTION_HIGH, ACTION_LOW, Observation, as_action, chunk_of


class Critic(Protocol):
    """What JITI needs from an elegance critic (`critics.load(dir)` returns one)."""

    def bind(self, metadata: Mapping[str, Any]) -> Any: ...

    def q(self, state: np.ndarray, actions: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class Decision:
    """One logged decision (every step for a per-step policy, the first step of each chunk for a chunked
    one): the base plan's score, the window statistics and what was executed. `step` is the env step.

    `mean`, `std`, `dq` and `tau` are None while the window warms up, outside mode "jiti" and without a critic;
    `q` and `chosen_q` are None only when JITI runs without a critic (modes "base" and "random").
    """

    step: int
    q: float | None
    mean: float | None
    std: float | None
    dq: float | None
    tau: float | None
    intervened: bool
    chosen: int
    chosen_q: float | None
    time: float
    # Diagnostics for intervened decisions: every candidate's Q (index 0 = the base plan) and how far the
    # executed plan is from the base plan (`plan_distance`); None when nothing was re-ranked.
    candidate_q: list[float] | None = None
    action_change: float | None = None


def as_plan(value: Any, chunk: int, source: str) -> np.ndarray:
    """A decision as a float64 (chunk, 7) plan clipped to the action bounds; refuse any other shape."""
    plan = np.asarray(value, dtype=np.float64)
    if plan.shape != (chunk, ACTION_DIM):
        raise UserInputError(f"{source} returned a plan of shape {plan.shape}; expected ({chunk}, {ACTION_DIM})")
    return np.clip(plan, ACTION_LOW, ACTION_HIGH)


def check_critic_chunk(critic: Any, chunk: int) -> None:
    """Refuse a critic that scores chunks of another length than the policy decides."""
    critic_chunk = int(getattr(critic, "chunk", 1))
    if critic_chunk != chunk:
        raise UserInputError(
            f"the critic scores chunks of {critic_chunk} actions but the policy decides {chunk} at a time: "
            f"train the critic with --chunk {chunk}"
        )


def decide(policy: Any, obs: Observation, chunk: int) -> np.ndarray:
    """The base decision of an adapted policy at `obs` as a (chunk, 7) plan: its action for a per-step
    policy (chunk 1), its `plan(obs)` for a `ChunkedPolicy`."""
    if chunk == 1:
        return as_action(policy(obs), "base policy")[None]
    return as_plan(policy.plan(obs), chunk, "base policy")


def draw_candidates(policy: Any, obs: Observation, plan: np.ndarray, n: int) -> np.ndarray:
    """n candidate plans (n, chunk, 7) for this decision, clipped to the action bounds, with candidate 0
    set to the base plan so it is always among them: from `policy.sample(obs, n)` (an adapted `Policy`)
    for a per-step policy (chunk 1), from `policy.sample_plans(obs, n)` for a `ChunkedPolicy`."""
    chunk = len(plan)
    if chunk == 1:
        drawn, call = np.asarray(policy.sample(obs, n), dtype=np.float64)[:, None], "sample"
    else:
        drawn, call = np.asarray(policy.sample_plans(obs, n), dtype=np.float64), "sample_plans"
    if drawn.shape != (n, chunk, ACTION_DIM):
        raise ValueError(
            f"{type(policy).__name__}.{call}(obs, {n}) returned shape {drawn.shape}, expected ({n}, {chunk}, "
            f"{ACTION_DIM}) with the chunk dimension"
        )
    candidates = np.clip(drawn, ACTION_LOW, ACTION_HIGH)
    candidates[0] = plan
    return candidates


def plan_distance(candidates: np.ndarray) -> np.ndarray:
    """(n,) distance of each candidate plan (n, chunk, 7) from candidate 0: the root mean square over the
    chunk's steps of the per-step L2 distance, so a trust radius means the same for any chunk length (for
    chunk 1 it is the L2 distance of the two actions)."""
    return np.sqrt(np.mean(np.sum((candidates - candidates[:1]) ** 2, axis=-1), axis=-1))


def _choice_rng(seed: int) -> np.random.Generator:
    """Mode "random"'s generator: a stream of its own, apart from the candidate noise the same seed drives."""
    return np.random.default_rng([int(seed), 0x6A697469])


def _state_of(obs: Observation) -> np.ndarray:
    if "state" not in obs:
        raise UserInputError(
            "JITI's critic needs the low-dimensional 'state' observation: make the env with obs='lowdim' or 'both'"
        )
    return np.asarray(obs["state"])


class JITI:
    """A policy (obs -> 7-D action) that wraps a base policy and intervenes at critical moments.

    `JITI(policy, critic)` runs with `JITIConfig`'s defaults; `JITI(policy, critic, config)` with a
    config; keyword settings (`JITI(policy, critic, window=4, trigger="drop")`) override either. `seed`
    seeds candidate sampling and mode "random"'s choices (each episode re-seeds them through `reset`);
    `random_steps`: mode "random" explores at the decisions taken at these steps instead of at a rate.
    The critic may be None in the modes that need none ("base", "random" and the critic-free controls).
    """

    def __init__(
        self,
        policy: Any,
        critic: Critic | None,
        config: JITIConfig | None = None,
        *,
        seed: int = 0,
        random_steps: Collection[int] | None = None,
        **settings: Any,
    ) -> None:
        cfg = config or JITIConfig()
        cfg = with_overrides(cfg, settings, "JITI") if settings else cfg
        mode = jiti_mode(cfg.mode)
        if critic is None and mode.needs_critic:
            raise UserInputError(f"JITI mode {cfg.mode!r} needs a critic: give one, or a mode that runs without")
        if critic is not None and not callable(getattr(critic, "q", None)):
            raise UserInputError(
                f"JITI critic: expected a critic object with q(state, actions) (e.g. critics.load(dir)), got {critic!r}"
            )
        self.settings = cfg
        self.policy = as_policy(policy, noise_scale=cfg.noise_scale, seed=seed)
        check_policy(mode, self.policy)
        self._mode = mode
        self.chunk = chunk_of(self.policy)
        if critic is not None:
            check_critic_chunk(critic, self.chunk)
        self.critic = critic
        # an ensemble (`critics.CriticEnsemble`) scores with every member; a plain critic is one member
        self._member_q = getattr(critic, "member_q", None)
        self._random_steps = None if random_steps is None else frozenset(int(t) for t in random_steps)
        self._trigger = mode.trigger(cfg, self._random_steps)
        self._selector = mode.selector(cfg)
        # only a mode that measures fluctuations logs window statistics: other runs record no window settings
        self._uses_window = mode.uses_window
        self._seed = seed
        self._rng = _choice_rng(seed)  # mode "random": when and what to choose
        self._scores: deque[float] = deque(maxlen=cfg.window)
        self._queue: deque[np.ndarray] = deque()
        self._step = 0
        self._overrides = 0
        self.log: list[Decision] = []

    @property
    def mode(self) -> str:
        return self.settings.mode

    def config(self) -> dict[str, Any]:
        """The settings that determine JITI's decisions (recorded with evaluation runs)."""
        return {**self.settings.record(), "chunk": self.chunk, "policy_adapter": type(self.policy).__name__}

    def with_mode(self, mode: str) -> JITI:
        """The same policy and critic under another mode (a gated run's tasks run in different modes)."""
        return JITI(
            self.policy,
            self.critic,
            replace(self.settings, mode=mode),
            seed=self._seed,
            random_steps=self._random_steps,
        )

    def reset(
        self,
        metadata: Mapping[str, Any] | None = None,
        *,
        seed: int | None = None,
        random_steps: Collection[int] | None = None,
    ) -> None:
        """Start an episode: reset the base policy (with `seed`, its candidate sampling restarts, so an
        episode does not depend on the ones before it), bind the critic to the env's state layout, and
        clear the window and the log. `random_steps`: mode "random" explores at these steps this episode
        (the branch of a recorded rollout); None keeps the agent's own."""
        if self.critic is not None and metadata is None:
            raise UserInputError("JITI.reset needs the env's metadata to bind the critic: call reset(env.metadata)")
        self.policy.reset(metadata, seed=seed)
        if seed is not None:
            self._rng = _choice_rng(seed)
        steps = self._random_steps if random_steps is None else frozenset(int(t) for t in random_steps)
        self._trigger = self._mode.trigger(self.settings, steps)
        if self.critic is not None:
            self.critic.bind(metadata)
        self._scores.clear()
        self._queue.clear()
        self._step = 0
        self._overrides = 0
        self.log = []

    def __call__(self, obs: Observation) -> np.ndarray:
        if self._queue:  # inside a chunk: the decision was taken at its first step
            self.policy.observe(obs)
            self._step += 1
            return self._queue.popleft()
        cfg = self.settings
        plan = decide(self.policy, obs, self.chunk)
        start = time.perf_counter()
        step, self._step = self._step, self._step + 1
        q = mean = std = dq = tau = None
        candidates = scores_c = member_scores = None
        if self.critic is not None:
            state = _state_of(obs)
            # plain Python: ~10x faster than numpy on a few floats
            if self._uses_window and len(self._scores) == cfg.window:
                mean = math.fsum(self._scores) / cfg.window
                std = math.sqrt(math.fsum((x - mean) ** 2 for x in self._scores) / cfg.window)
                tau = cfg.threshold if cfg.threshold_mode == "absolute" else cfg.threshold * std
            if self._trigger.every_decision:  # all candidates in one batch
                candidates = self._candidates(obs, plan)
                member_scores = self._score(state, candidates)
            else:
                member_scores = self._score(state, plan[None])
            q = float(member_scores[:, 0].mean())
            if mean is not None:
                dq = abs(q - mean)
        if candidates is None:
            if self._trigger.fires(Moment(step, q, mean, tau, self._overrides, self._rng)):
                candidates = self._candidates(obs, plan)
                if self.critic is not None:  # the base plan's scores are known: only the alternatives are new
                    alternatives = self._score(state, candidates[1:])
                    member_scores = np.concatenate([member_scores[:, :1], alternatives], axis=1)
        chosen, chosen_q, executed, distance = 0, q, plan, None
        if candidates is not None:
            distance = plan_distance(candidates)
            scores_c = None if self.critic is None else member_scores.mean(axis=0)
            log_prob = lambda: self.policy.log_prob_plans(obs, candidates)  # noqa: E731 (asked for on demand)
            chosen = self._selector.select(Choice(candidates, member_scores, distance, self._rng, log_prob))
            executed = candidates[chosen]
            self._overrides += chosen != 0
            chosen_q = None if scores_c is None else float(scores_c[chosen])
        if chosen_q is not None and self._uses_window:
            self._scores.append(chosen_q)
        elapsed = time.perf_counter() - start
        self.log.append(
            Decision(
                step,
                q,
                mean,
                std,
                dq,
                tau,
                candidates is not None,
                chosen,
                chosen_q,
                elapsed,
                candidate_q=None if scores_c is None else [round(float(x), 4) for x in scores_c],
                action_change=None if distance is None else float(distance[chosen]),
            )
        )
        return self._execute(executed)

    def _execute(self, plan: np.ndarray) -> np.ndarray:
        self._queue.extend(plan[1:])
        return plan[0].copy()

    def _candidates(self, obs: Observation, plan: np.ndarray) -> np.ndarray:
        return draw_candidates(self.policy, obs, plan, self.settings.n_candidates)

    def _score(self, state: np.ndarray, plans: np.ndarray) -> np.ndarray:
        """(members, n) scores of the plans: one row for a plain critic, one per member for an ensemble."""
        flat = plans.reshape(len(plans), -1)
        if self._member_q is None:
            scores = np.asarray(self.critic.q(state, flat), dtype=np.float64).reshape(1, -1)
        else:
            scores = np.asarray(self._member_q(state, flat), dtype=np.float64)
        if scores.ndim != 2 or scores.shape[1] != len(plans):
            raise ValueError(f"the critic returned scores of shape {scores.shape} for {len(plans)} actions")
        return scores

    @property
    def interventions(self) -> int:
        """Decisions of the current episode at which candidates were drawn and re-ranked."""
        return sum(d.intervened for d in self.log)

    @property
    def overrides(self) -> int:
        """Decisions of the current episode at which an alternative replaced the base plan."""
        return self._overrides

    def trace(self) -> dict[str, list]:
        """The episode's decision log as columns (JSON-ready), one list per `Decision` field."""
        fields = Decision.__dataclass_fields__
        rows = [asdict(d) for d in self.log]
        return {name: [row[name] for row in rows] for name in fields}
