"""The one rollout loop: an actor stepped through an episode, with observers that watch each step.

Evaluation, recorded demos and rollouts, branching diagnostics and the benchmarks all run episodes
through `run_episode`; what each of them needs from an episode (ITC labels, the arrays of the demo
format, a decision trace, an early stop) is an observer, not another loop. The loop times the env's step
alone, so a decision's cost can be told from the simulator's.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

Observation = Mapping[str, np.ndarray]


class StepObserver:
    """Watches one episode's steps. `before_step` sees the observation the actor is about to act on (the
    simulator still in that state); `after_step` the executed action and what the env returned, and may
    return True to end the episode there. Both do nothing by default."""

    def before_step(self, env: Any, obs: Observation) -> None:
        return None

    def after_step(
        self, env: Any, action: np.ndarray, obs: Observation, reward: float, info: Mapping[str, Any]
    ) -> bool:
        return False


@dataclass
class EpisodeRun:
    """What the loop saw: steps taken, the env's last info and observation, how the episode ended, and the
    seconds spent inside `env.step`."""

    steps: int = 0
    info: dict[str, Any] = field(default_factory=lambda: {"success": False, "perturbation": []})
    obs: Observation | None = None
    terminated: bool = False
    truncated: bool = False
    stopped: bool = False
    env_time: float = 0.0


def run_episode(
    env: Any,
    act: Callable[[Observation], Any],
    obs: Observation,
    observers: Sequence[StepObserver] = (),
    max_steps: int | None = None,
) -> EpisodeRun:
    """Run `act` (obs -> 7-D action) from `obs`, the env's just-reset observation, until the env ends the
    episode, an observer stops it, or `max_steps` (default: the env's horizon) steps were taken."""
    run = EpisodeRun(obs=obs)
    for _ in range(env.max_steps if max_steps is None else max_steps):
        for observer in observers:
            observer.before_step(env, obs)
        action = np.asarray(act(obs), dtype=np.float64)
        start = time.perf_counter()
        obs, reward, terminated, truncated, info = env.step(action)
        run.env_time += time.perf_counter() - start
        run.steps += 1
        run.obs, run.info, run.terminated, run.truncated = obs, info, bool(terminated), bool(truncated)
        for observer in observers:
            run.stopped |= bool(observer.after_step(env, action, obs, reward, info))
        if terminated or truncated or run.stopped:
            break
    return run


class ActionLog(StepObserver):
    """The actions an episode executed, exactly as `env.step` received them: with the episode's start and
    reset seed they replay it bit for bit (the env is deterministic), e.g. to render it afterwards."""

    def __init__(self) -> None:
        self.actions: list[np.ndarray] = []

    def after_step(
        self, env: Any, action: np.ndarray, obs: Observation, reward: float, info: Mapping[str, Any]
    ) -> bool:
        self.actions.append(np.array(action, dtype=np.float64))
        return False

    def array(self) -> np.ndarray:
        """(T, 7) float64."""
        return np.stack(self.actions) if self.actions else np.zeros((0, 7))
