"""The one rollout loop: the order in which observers see a step, how an episode ends (the env, an
observer, or a step limit), and what the loop reports. A stand-in env counts steps; the real simulator
runs through this loop in every evaluation, recording and annotation test."""

from __future__ import annotations

import numpy as np

from base_suites.rollout import StepObserver, run_episode


class CountingEnv:
    """obs["t"] is the step count; the episode terminates at `end` (success) or truncates at `max_steps`."""

    def __init__(self, end: int | None = None, max_steps: int = 10) -> None:
        self.end, self.max_steps, self.t, self.actions = end, max_steps, 0, []

    def step(self, action):
        self.actions.append(action)
        self.t += 1
        terminated = self.end is not None and self.t >= self.end
        truncated = self.t >= self.max_steps
        return (
            {"t": np.array([self.t])},
            float(self.t),
            terminated,
            truncated,
            {"success": terminated, "perturbation": []},
        )


class Log(StepObserver):
    def __init__(self, events, stop_at=None):
        self.events, self.stop_at = events, stop_at

    def before_step(self, env, obs):
        self.events.append(("before", int(obs["t"][0])))

    def after_step(self, env, action, obs, reward, info):
        self.events.append(("after", int(obs["t"][0]), float(action[0]), reward))
        return self.stop_at is not None and int(obs["t"][0]) >= self.stop_at


def act(obs):
    return [float(obs["t"][0])] + [0.0] * 6  # a list: the loop hands the env a float64 array


def test_observers_see_each_step_before_and_after_and_the_env_ends_the_episode():
    env, events = CountingEnv(end=3), []
    run = run_episode(env, act, {"t": np.array([0])}, [Log(events)])
    assert events == [
        ("before", 0),
        ("after", 1, 0.0, 1.0),
        ("before", 1),
        ("after", 2, 1.0, 2.0),
        ("before", 2),
        ("after", 3, 2.0, 3.0),
    ]
    assert (run.steps, run.terminated, run.truncated, run.stopped, run.info["success"]) == (3, True, False, False, True)
    assert all(isinstance(a, np.ndarray) and a.dtype == np.float64 for a in env.actions)
    assert int(run.obs["t"][0]) == 3 and run.env_time >= 0.0


def test_an_observer_or_a_step_limit_ends_the_episode_early():
    events = []
    run = run_episode(CountingEnv(), act, {"t": np.array([0])}, [Log(events, stop_at=2), Log([])])
    assert (run.steps, run.stopped, run.terminated) == (2, True, False)
    assert run_episode(CountingEnv(), act, {"t": np.array([0])}, max_steps=4).steps == 4
    truncated = run_episode(CountingEnv(max_steps=5), act, {"t": np.array([0])})
    assert (truncated.steps, truncated.truncated, truncated.info["success"]) == (5, True, False)
