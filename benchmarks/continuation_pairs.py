"""Clean-vs-knob continuation pairs of the scripted expert, and how often a critic prefers the clean side.

From the same state, does Q prefer what the clean scripted expert did over what the same expert did with
a quality knob applied? `continuation_pairs` branches a clean and a knob rollout where the knob first
changes an action; `pair_preference` reports how often the clean continuation scores higher. Used by
`critic_pairs.py`; it needs the simulator.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from annotations import task_key
from base_suites.env import LiberoEnv
from base_suites.experts import ScriptedExpert
from base_suites.rollout import StepObserver, run_episode
from base_suites.runtime.errors import UserInputError, unknown_choice
from base_suites.runtime.seeds import derive_seed
from critics.data import action_chunks


@dataclass(frozen=True, eq=False)
class Continuation:
    """One side of a pair: the states seen (env `obs["state"]`, (T, D)) and the actions taken ((T, 7))
    from the branching step on."""

    states: np.ndarray
    actions: np.ndarray


@dataclass(frozen=True, eq=False)
class Pair:
    """A clean and a knob continuation of the same expert episode from the state where they branch.

    `branch_step` is the first step whose action differs (t*): both sides start from the same state there,
    so any difference in their Q is about what was done, not where it was done from.
    """

    task: str
    init: int
    knob: str
    branch_step: int
    clean: Continuation
    knobbed: Continuation


class PairList(list):
    """The pairs of one task, with what scoring them needs and what was left out.

    `metadata` is the env's (bind a critic to it); `skipped` counts, per knob, the init states where the
    knob never changed an action (nothing to compare).
    """

    def __init__(self, pairs: Sequence[Pair], metadata: Mapping[str, Any], skipped: Mapping[str, int]) -> None:
        super().__init__(pairs)
        self.metadata = dict(metadata)
        self.skipped = dict(skipped)


class Scorer(Protocol):
    """Anything with the run-time critic's `q` (a bound `Critic`, or a stand-in in tests)."""

    def q(self, state: np.ndarray, actions: np.ndarray) -> np.ndarray: ...


class _StepRecording(StepObserver):
    """Records (state, action) of each step. Given the clean episode's actions, it stops the episode
    `window` steps after the first action that differs from them (the branch step t*), or once the clean
    episode's steps are used up without a difference (the knob never acted)."""

    def __init__(self, clean_actions: Sequence[np.ndarray] | None = None, window: int = 0) -> None:
        self.steps: list[tuple[np.ndarray, np.ndarray]] = []
        self.clean, self.window = clean_actions, window
        self.branch: int | None = None
        self._state: np.ndarray | None = None

    def before_step(self, env: LiberoEnv, obs: Mapping[str, np.ndarray]) -> None:
        self._state = obs["state"]

    def after_step(self, env: LiberoEnv, action: np.ndarray, obs: Any, reward: float, info: Any) -> bool:
        t = len(self.steps)
        self.steps.append((self._state, action))
        if self.clean is None:
            return False
        if self.branch is None:
            if not np.array_equal(action, self.clean[t]):
                self.branch = t
            elif t == len(self.clean) - 1:
                return True  # the clean episode's last step, and still no difference: nothing to compare
        return self.branch is not None and t - self.branch + 1 >= self.window


def _episode(env: LiberoEnv, expert: ScriptedExpert, init: int, reset_seed: int, recording: _StepRecording) -> None:
    """One expert episode from a given start through the one rollout loop, watched by `recording`.

    The reset seed fixes the scene and the episode number (the init index) fixes the expert's RNG, so a
    clean and a knob expert replay the same steps until the knob first acts.
    """
    obs, _ = env.reset(seed=reset_seed, options={"init_state": init})
    expert.reset(env.metadata, episode=init)
    run_episode(env, expert, obs, [recording])


def _continuation(steps: Sequence[tuple[np.ndarray, np.ndarray]]) -> Continuation:
    return Continuation(np.array([s for s, _ in steps]), np.array([a for _, a in steps]))


def _check_pair_inputs(knobs: Sequence[str], inits: Sequence[int], window: int) -> None:
    from base_suites.experts import KNOBS

    for knob in knobs:
        if knob not in KNOBS:
            raise unknown_choice("knob", knob, KNOBS)
    if not knobs or not inits:
        raise UserInputError("continuation_pairs: give at least one knob and one init state")
    if window < 1:
        raise UserInputError(f"continuation_pairs: window must be >= 1 step, got {window}")


def continuation_pairs(
    suite: str,
    task: int | str,
    knobs: Sequence[str],
    inits: Sequence[int],
    seed: int,
    window: int = 25,
    max_steps: int | None = None,
) -> PairList:
    """Clean-vs-knob continuation pairs of the scripted expert on one task.

    For each init state and knob, runs the clean expert and the expert with that knob always on (same
    expert seed, episode number and env reset seed), finds the first step t* where their actions differ,
    and keeps each side's states and actions for steps t*..t*+window-1 (fewer if its episode ends first).
    Inits where the knob never acts are counted in `skipped`. `max_steps` caps the episode length (default:
    the task's horizon).
    """
    from base_suites.env import make_env

    _check_pair_inputs(knobs, inits, window)
    env = make_env(suite, task, seed=seed, max_steps=max_steps)
    key = task_key(env.task.suite, env.task.index)
    clean = ScriptedExpert(env, "clean", seed=seed)
    experts = {knob: ScriptedExpert(env, {knob: 1.0}, seed=seed) for knob in knobs}
    pairs, skipped = [], {knob: 0 for knob in knobs}
    try:
        for init in inits:
            reset_seed = derive_seed(seed, init)
            clean_run = _StepRecording()
            _episode(env, clean, init, reset_seed, clean_run)
            clean_actions = [a for _, a in clean_run.steps]
            for knob, expert in experts.items():
                knob_run = _StepRecording(clean_actions, window)
                _episode(env, expert, init, reset_seed, knob_run)
                t = knob_run.branch
                if t is None:
                    skipped[knob] += 1
                    continue
                clean_side = _continuation(clean_run.steps[t : t + window])
                pairs.append(Pair(key, int(init), knob, t, clean_side, _continuation(knob_run.steps[t:])))
        return PairList(pairs, env.metadata, skipped)
    finally:
        env.close()


def _side_score(critic: Scorer, side: Continuation, steps: int) -> float:
    """Mean Q over a side's first `steps` steps: how good the critic finds that stretch of behaviour."""
    return float(
        np.mean(
            critic.q(side.states[:steps], action_chunks(side.actions, getattr(critic, "chunk", 1))[:steps, None, :])[
                :, 0
            ]
        )
    )


def _gap(critic: Scorer, pair: Pair) -> float:
    """Clean minus knob score over the same number of steps: a side that ends sooner (the episode
    succeeded) would otherwise be scored on its near-terminal states only, where Q is high anyway."""
    steps = min(len(pair.clean.actions), len(pair.knobbed.actions))
    return _side_score(critic, pair.clean, steps) - _side_score(critic, pair.knobbed, steps)


def _preference_summary(gaps: np.ndarray) -> dict[str, Any]:
    wins = int((gaps > 0).sum())
    return {
        "pairs": int(len(gaps)),
        "clean_wins": wins,
        "clean_preferred": wins / len(gaps) if len(gaps) else None,
        "mean_gap": float(gaps.mean()) if len(gaps) else None,
    }


def pair_preference(critic: Scorer, pairs: Sequence[Pair]) -> dict[str, Any]:
    """How often Q prefers the clean continuation to the knob one from the same state.

    A side's score is the mean Q of its steps (both sides over the length of the shorter); the clean side wins
    a pair only when it scores strictly higher (a tie is no preference). A critic that has learnt elegance
    should prefer what the clean expert did; issue 5 asks for >= 80% of pairs. Returns pairs, clean_wins,
    clean_preferred (the fraction; None without pairs), mean_gap (clean minus knob score), and the same per
    knob. `critic` must already be bound to the pairs' task (e.g. `load(dir).bind(pairs.metadata)`).
    """
    gaps = np.array([_gap(critic, p) for p in pairs], dtype=np.float64)
    knob_of = np.array([p.knob for p in pairs], dtype=object)
    per_knob = {knob: _preference_summary(gaps[knob_of == knob]) for knob in dict.fromkeys(p.knob for p in pairs)}
    return {**_preference_summary(gaps), "per_knob": per_knob}
