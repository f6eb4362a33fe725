"""JITI: just-in-time intervention of an elegance critic on a base policy (DESIGN.md section 5).

Re-ranking sampled actions at every step (V-GPS) overrides a good base policy all the time and pays for
N samples and N critic scores per step. JITI instead watches the critic's score of the action the base
policy proposes, q_t = Q(s_t, a_t), against the mean m_t of the last `window` scores. Only when
dq_t = |q_t - m_t| exceeds the threshold tau (a critical moment: the critic sees the situation change)
does it draw N candidates from the base policy, with a_t kept as candidate 0, and execute the one the
critic scores highest.

Choices made here, each for a reason:
- Warm-up: m_t needs `window` past scores, so no fluctuation can be measured until the window is full.
  A mean of two or three scores would make the very first steps look critical. With `warmup="base"`
  (DESIGN.md's rule, the default) the first `window` decisions execute the base plan; with
  `warmup="steer"` JITI re-selects them as mode "always" does. The start of an episode is a critical
  moment that no fluctuation can reveal: the policy commits to its approach and grasp there, before
  the critic has a reference. On libero_object the base policy's commonest flaw is tipping the can it
  approaches within the first 40 steps. With the same critics, the drop trigger alone cost 2.8 points
  of ESR on held-out starts, and steering the first 4 decisions as well gained 8.8 (9.2 with
  `trigger="none"`, the warm-up alone), more than `always`'s 6.4 at a quarter of its interventions
  (benchmarks/RESULTS.md, session 27). Running JITI only on the tasks a validation gate enables
  (`elegant.intervention.gate`) raised the gain to 11.6 (session 28).
- The window receives the score of the action actually executed (q_t, or the chosen candidate's score
  after an intervention): the window tracks the value of the trajectory being followed, so after a
  successful correction the new level becomes the reference instead of triggering again.
- tau is absolute, or in units of the window's standard deviation (`threshold_mode="std"`), which
  makes it independent of the critic's scale. The absolute default of 1.0 is one step of elegance
  reward: along a consistent trajectory Q_t - Q_{t+1} = r_t - (1 - gamma) Q_{t+1} lies in [-1, 1]
  (r in [0, 1], Q <= 1 / (1 - gamma)) and is far smaller while the reward is steady, so a deviation of
  more than 1 from the recent level marks an event rather than drift.
- `trigger="drop"` intervenes only when q_t falls more than tau below m_t. A critic trained on the
  outcome predicts a value that climbs as the task progresses, and the symmetric dq then fires along
  the whole climb (the mean lags behind): with the libero_goal/1 chunk critic, window 4 and tau one
  running std, JITI intervened at 10 of an episode's 13 decisions, nearly every one after the warm-up,
  and overriding a good policy that often spoiled its placements. A fall is the event that matters:
  the critic expects the trajectory to end worse than it did a moment ago. The default stays the
  symmetric deviation of DESIGN.md.
- Ties in the argmax go to candidate 0, the base action: JITI never overrides without a reason. With
  `min_gain` > 0 the best candidate must also beat the base action's score by more than `min_gain`: a
  critic's scores of actions a few millimetres apart differ by its noise (with the libero_goal critic
  the median gain of a chosen alternative was 0.01, on returns in [-10, 0]), and an override on noise
  is a random perturbation of a policy whose elegant executions are fragile.
- An ensemble critic (`critics.CriticEnsemble`, e.g. critics trained on bootstrap resamples of the
  data) is watched through its mean Q, and a candidate replaces the base action only if every member
  scores it higher (by `min_gain`): one critic's ranking of alternatives on new starts is barely better
  than chance, and where critics trained on different resamples disagree the data did not decide. On
  libero_goal/1 and /4 three bootstrap critics overrode a third less often than one and spoiled no
  episode (benchmarks/RESULTS.md, session 25).
- `max_overrides` caps the alternatives executed per episode. Overrides compound: once one has moved the
  robot off the policy's course, the critic can score every later base plan far below the alternatives
  and override again and again (on libero_goal/0 the episodes JITI spoiled had 5 to 19 overrides; those
  it made elegant on libero_goal/4 had 1 or 2). A budget of 3 kept the ESR of libero_object 0-4 at a
  third fewer interventions, but did not save those goal/0 episodes: their first override spoils them.
- Candidates: the base policy is adapted with `elegant.policies.as_policy`, so they come from its own
  `sample(obs, N)` when it has one (GMM, diffusion noise, a stochastic TorchRL module) and otherwise
  from the adapter's seeded Gaussian perturbations of a_t, clipped to the action bounds. Candidate 0
  is always set to a_t itself, so exactly N candidates are scored and the base action is among them.
- Decision time is what JITI adds to a step: scoring, bookkeeping and, at interventions, candidate
  sampling. The base policy's own forward pass is excluded because it is paid without JITI too.
- Action chunks: a `ChunkedPolicy` decides `chunk` actions at once and executes them open-loop. JITI then
  decides at the policy's decision points only: it scores the base chunk with a critic trained on chunks
  of the same length (Q(s_t, a_t..a_{t+chunk-1})), and at a critical moment chooses among N chunks from
  the policy's `sample_plans`. One choice then changes the next `chunk` steps coherently, where a single
  re-ranked 50 ms action barely moves the robot (`benchmarks/jiti_headroom.py` measured that one-step
  changes near the base action almost never turn an inelegant episode elegant). The window, the
  threshold and the log count decisions; a per-step policy is the case chunk = 1.
- Mode "random" intervenes at a random `random_rate` of decisions with a uniformly random eligible
  candidate, critic or not: the control that tells whether the critic's choice (and its timing) matters,
  and the exploration that gives recorded rollouts (`elegant rollouts`) alternatives with known outcomes.
  With `random_steps` set it intervenes exactly at the decisions taken at those steps instead: rollouts
  that share a prefix and differ in one chosen decision, the contrasts a critic must rank.
"""
from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Collection, Mapping
from dataclasses import asdict, dataclass
from typing import Any, Protocol

import numpy as np

from base_suites.runtime.errors import UserInputError, unknown_choice
from elegant.policies.adapters import as_policy
from elegant.policies.protocol import ACTION_DIM, ACTION_HIGH, ACTION_LOW, Observation, as_action, chunk_of

MODES = ("jiti", "always", "base", "random")
THRESHOLD_MODES = ("absolute", "std")
TRIGGERS = ("deviation", "drop", "none")
WARMUPS = ("base", "steer")
DEFAULT_THRESHOLD = 1.0
DEFAULT_NOISE_SCALE = 0.1


class Critic(Protocol):
    """What JITI needs from an elegance critic (`critics.load(dir)` returns one)."""

    def bind(self, metadata: Mapping[str, Any]) -> Any: ...

    def q(self, state: np.ndarray, actions: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class Decision:
    """One logged decision (every step for a per-step policy, the first step of each chunk for a chunked
    one): the base plan's score, the window statistics and what was executed. `step` is the env step.

    `mean`, `std`, `dq` and `tau` are None while the window warms up (or without a critic);
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
        raise ValueError(f"{type(policy).__name__}.{call}(obs, {n}) returned shape {drawn.shape}, expected ({n}, {chunk}, {ACTION_DIM}) with the chunk dimension")
    candidates = np.clip(drawn, ACTION_LOW, ACTION_HIGH)
    candidates[0] = plan
    return candidates


def plan_distance(candidates: np.ndarray) -> np.ndarray:
    """(n,) distance of each candidate plan (n, chunk, 7) from candidate 0: the root mean square over the
    chunk's steps of the per-step L2 distance, so a trust radius means the same for any chunk length (for
    chunk 1 it is the L2 distance of the two actions)."""
    return np.sqrt(np.mean(np.sum((candidates - candidates[:1]) ** 2, axis=-1), axis=-1))


def eligible_candidates(distance: np.ndarray, trust_radius: float | None) -> np.ndarray:
    """Which candidates may be chosen: those whose `distance` (`plan_distance` from candidate 0, the base
    plan) is within `trust_radius` (all of them without one)."""
    distance = np.asarray(distance)
    return np.ones(distance.shape, dtype=bool) if trust_radius is None else distance <= trust_radius


def choose_candidate(scores: np.ndarray, distance: np.ndarray, trust_radius: float | None, min_gain: float = 0.0) -> int:
    """Index of the best eligible candidate (`eligible_candidates`), or 0, the base action.

    `scores` is (n,) for one critic or (members, n) for an ensemble (`critics.CriticEnsemble.member_q`).
    A candidate can replace the base action only if every member scores it more than `min_gain` above
    the base action; among those the best mean score wins (the first maximum). So JITI never overrides
    without a reason, and with an ensemble not on one member's say."""
    members = np.atleast_2d(np.asarray(scores, dtype=np.float64))
    agreed = np.all(members - members[:, :1] > min_gain, axis=0) & eligible_candidates(distance, trust_radius)
    if not agreed.any():
        return 0
    return int(np.argmax(np.where(agreed, members.mean(axis=0), -np.inf)))


def check_trigger_and_warmup(trigger: str | None, warmup: str | None, jiti_mode: bool, owner: str = "JITI") -> None:
    """Refuse an unknown trigger or warm-up, and, when mode "jiti" runs (`jiti_mode`), settings under
    which it could never intervene and would run as a silent base policy: trigger "none" without a
    steered warm-up. None stands for JITI's default. `owner` names the settings in the error."""
    if trigger is not None and trigger not in TRIGGERS:
        raise unknown_choice(f"{owner} trigger", trigger, TRIGGERS)
    if warmup is not None and warmup not in WARMUPS:
        raise unknown_choice(f"{owner} warmup", warmup, WARMUPS)
    if jiti_mode and trigger == "none" and warmup != "steer":
        raise UserInputError("JITI trigger 'none' never intervenes unless the warm-up is steered (warmup='steer')")


def check_candidates(n_candidates: int, setting: str = "JITI n_candidates") -> None:
    """Refuse fewer than two candidates per decision: the base action and at least one alternative.
    `setting` names the value in the error, as its owner (JITI, a chain) calls it."""
    if int(n_candidates) < 2:
        raise UserInputError(f"{setting} must be >= 2 (the base action plus alternatives), got {n_candidates}")


def _choice_rng(seed: int) -> np.random.Generator:
    """Mode "random"'s generator: a stream of its own, apart from the candidate noise the same seed drives."""
    return np.random.default_rng([int(seed), 0x6A697469])


def _state_of(obs: Observation) -> np.ndarray:
    if "state" not in obs:
        raise UserInputError("JITI's critic needs the low-dimensional 'state' observation: make the env with obs='lowdim' or 'both'")
    return np.asarray(obs["state"])


class JITI:
    """A policy (obs -> 7-D action) that wraps a base policy and intervenes at critical moments.

    Modes: "jiti" (intervene when dq > tau), "always" (re-select at every decision: the V-GPS baseline),
    "base" (never intervene, still log the critic's scores; the critic may then be None), "random"
    (intervene at a random `random_rate` of decisions with a random eligible candidate; critic optional).
    """

    def __init__(
        self,
        policy: Any,
        critic: Critic | None,
        window: int = 10,
        threshold: float = DEFAULT_THRESHOLD,
        threshold_mode: str = "absolute",
        n_candidates: int = 16,
        mode: str = "jiti",
        noise_scale: float = DEFAULT_NOISE_SCALE,
        seed: int = 0,
        trust_radius: float | None = None,
        random_rate: float = 0.1,
        min_gain: float = 0.0,
        random_steps: Collection[int] | None = None,
        trigger: str = "deviation",
        max_overrides: int | None = None,
        warmup: str = "base",
    ) -> None:
        if mode not in MODES:
            raise unknown_choice("JITI mode", mode, MODES)
        if threshold_mode not in THRESHOLD_MODES:
            raise unknown_choice("JITI threshold_mode", threshold_mode, THRESHOLD_MODES)
        check_trigger_and_warmup(trigger, warmup, jiti_mode=mode == "jiti")
        if int(window) < 1:
            raise UserInputError(f"JITI window must be >= 1, got {window}")
        check_candidates(n_candidates)
        if float(threshold) < 0 or float(noise_scale) < 0:
            raise UserInputError(f"JITI threshold and noise_scale must be >= 0, got {threshold} and {noise_scale}")
        if trust_radius is not None and float(trust_radius) <= 0:
            raise UserInputError(f"JITI trust_radius must be > 0 (or None for no limit), got {trust_radius}")
        if critic is None and mode not in ("base", "random"):
            raise UserInputError(f"JITI mode {mode!r} needs a critic; only modes 'base' and 'random' run without one")
        if not float(min_gain) >= 0:
            raise UserInputError(f"JITI min_gain must be >= 0, got {min_gain}")
        if not 0.0 <= float(random_rate) <= 1.0:
            raise UserInputError(f"JITI random_rate must lie in [0, 1], got {random_rate}")
        if max_overrides is not None and int(max_overrides) < 0:
            raise UserInputError(f"JITI max_overrides must be >= 0 (or None for no limit), got {max_overrides}")
        self.policy = as_policy(policy, noise_scale=noise_scale, seed=seed)
        self.chunk = chunk_of(self.policy)
        if critic is not None:
            check_critic_chunk(critic, self.chunk)
        self.critic = critic
        # an ensemble (`critics.CriticEnsemble`) scores with every member; a plain critic is one member
        self._member_q = getattr(critic, "member_q", None)
        self.window = int(window)
        self.threshold = float(threshold)
        self.threshold_mode = threshold_mode
        self.trigger = trigger
        # mode "jiti": what the decisions before the window is full execute, the base plan or the critic's choice
        self.warmup = warmup
        self.n_candidates = int(n_candidates)
        self.mode = mode
        self.noise_scale = float(noise_scale)
        # Candidates farther than this (L2 over the action) from the base action are not eligible: a
        # critic trained on a few demos ranks far-off samples (another GMM mode, a gripper flip) badly.
        self.trust_radius = None if trust_radius is None else float(trust_radius)
        self.random_rate = float(random_rate)
        self.min_gain = float(min_gain)
        # mode "jiti": after this many overrides in an episode, JITI stops intervening (None: no limit)
        self.max_overrides = None if max_overrides is None else int(max_overrides)
        # mode "random": intervene at the decisions taken at these steps, not at a random rate (settable per episode)
        self.random_steps = None if random_steps is None else frozenset(int(t) for t in random_steps)
        self._rng = _choice_rng(seed)  # mode "random": when and what to choose
        self._scores: deque[float] = deque(maxlen=self.window)
        self._queue: deque[np.ndarray] = deque()
        self._step = 0
        self._overrides = 0
        self.log: list[Decision] = []

    def config(self) -> dict[str, Any]:
        """The settings that determine JITI's decisions (recorded with evaluation runs)."""
        return {
            "mode": self.mode,
            "window": self.window,
            "threshold": self.threshold,
            "threshold_mode": self.threshold_mode,
            "n_candidates": self.n_candidates,
            "noise_scale": self.noise_scale,
            "trust_radius": self.trust_radius,
            "random_rate": self.random_rate,
            "min_gain": self.min_gain,
            "trigger": self.trigger,
            "warmup": self.warmup,
            "max_overrides": self.max_overrides,
            "chunk": self.chunk,
            "policy_adapter": type(self.policy).__name__,
        }

    def reset(self, metadata: Mapping[str, Any] | None = None, *, seed: int | None = None) -> None:
        """Start an episode: reset the base policy (with `seed`, its candidate sampling restarts, so an
        episode does not depend on the ones before it), bind the critic to the env's state layout, and
        clear the window and the log."""
        if self.critic is not None and metadata is None:
            raise UserInputError("JITI.reset needs the env's metadata to bind the critic: call reset(env.metadata)")
        self.policy.reset(metadata, seed=seed)
        if seed is not None:
            self._rng = _choice_rng(seed)
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
        plan = decide(self.policy, obs, self.chunk)
        start = time.perf_counter()
        step, self._step = self._step, self._step + 1
        q = mean = std = dq = tau = None
        candidates = scores_c = member_scores = None
        if self.critic is not None:
            state = _state_of(obs)
            if len(self._scores) == self.window:  # plain Python: ~10x faster than numpy on 10 floats
                mean = math.fsum(self._scores) / self.window
                std = math.sqrt(math.fsum((x - mean) ** 2 for x in self._scores) / self.window)
                tau = self.threshold if self.threshold_mode == "absolute" else self.threshold * std
            if self.mode == "always":
                candidates = self._candidates(obs, plan)
                member_scores = self._score(state, candidates)
            else:
                member_scores = self._score(state, plan[None])
            q = float(member_scores[:, 0].mean())
            if mean is not None:
                dq = abs(q - mean)
        critical = dq is not None and self._critical(q, mean, dq, tau)
        steered_warmup = self.warmup == "steer" and mean is None
        intervene = (self.mode == "jiti" and (critical or steered_warmup) and not self._budget_spent()) or \
            (self.mode == "random" and self._explores(step))
        if intervene:
            candidates = self._candidates(obs, plan)
            if self.critic is not None:  # the base plan's scores are known: only the alternatives are new
                member_scores = np.concatenate([member_scores[:, :1], self._score(state, candidates[1:])], axis=1)
        chosen, chosen_q, executed, distance = 0, q, plan, None
        if candidates is not None:
            distance = plan_distance(candidates)
            scores_c = None if self.critic is None else member_scores.mean(axis=0)
            chosen = self._random_choice(distance) if self.mode == "random" else choose_candidate(member_scores, distance, self.trust_radius, self.min_gain)
            executed = candidates[chosen]
            self._overrides += chosen != 0
            chosen_q = None if scores_c is None else float(scores_c[chosen])
        if chosen_q is not None:
            self._scores.append(chosen_q)
        elapsed = time.perf_counter() - start
        self.log.append(
            Decision(
                step, q, mean, std, dq, tau, candidates is not None, chosen, chosen_q, elapsed,
                candidate_q=None if scores_c is None else [round(float(x), 4) for x in scores_c],
                action_change=None if distance is None else float(distance[chosen]),
            )
        )
        return self._execute(executed)

    def _critical(self, q: float, mean: float, dq: float, tau: float) -> bool:
        """Whether a decision scored `q`, with a full window of mean `mean`, is a critical moment."""
        if self.trigger == "deviation":
            return dq > tau
        if self.trigger == "drop":
            return mean - q > tau
        return False  # "none": only a steered warm-up intervenes

    def _budget_spent(self) -> bool:
        """Whether this episode's overrides reached `max_overrides`."""
        return self.max_overrides is not None and self.overrides >= self.max_overrides

    def _explores(self, step: int) -> bool:
        """Mode "random": whether the decision at `step` gets a random candidate."""
        return step in self.random_steps if self.random_steps is not None else self._rng.random() < self.random_rate

    def _random_choice(self, distance: np.ndarray) -> int:
        """Mode "random": a uniformly random eligible alternative to the base plan (the base plan if none is)."""
        eligible = np.flatnonzero(eligible_candidates(distance, self.trust_radius)[1:]) + 1
        return int(self._rng.choice(eligible)) if len(eligible) else 0

    def _execute(self, plan: np.ndarray) -> np.ndarray:
        self._queue.extend(plan[1:])
        return plan[0].copy()

    def _candidates(self, obs: Observation, plan: np.ndarray) -> np.ndarray:
        return draw_candidates(self.policy, obs, plan, self.n_candidates)

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
