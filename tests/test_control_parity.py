"""The fast control path (`base_suites.control`) against robosuite's own step: from the same init state
and actions, the same MuJoCo state after every step, bit for bit, and the same success. Random actions on
one task of each suite and under each perturbation; the scripted expert through the articulated fixtures
(a drawer, the stove knob, the microwave door), whose joints random actions barely move."""

from __future__ import annotations

import numpy as np
import pytest

from base_suites import make_env
from base_suites.experts import ScriptedExpert

pytestmark = pytest.mark.sim


def trajectory(suite, task, physics, actions=None, perturbation=None, expert_steps=0):
    """(states after every step, successes) of one episode from init state 1 with reset seed 3."""
    env = make_env(suite, task, seed=0, physics=physics, max_steps=10**6, perturbation=perturbation)
    try:
        obs, _ = env.reset(seed=3, options={"init_state": 1})
        expert = None
        if expert_steps:
            expert = ScriptedExpert(env, "clean", seed=0)
            expert.reset(env.metadata, episode=1)
        states, successes = [], []
        for t in range(expert_steps or len(actions)):
            obs, reward, terminated, _, _ = env.step(expert(obs) if expert else actions[t])
            states.append(env.get_sim_state())
            successes.append(reward)
            if terminated:
                break
        return np.array(states), successes
    finally:
        env.close()


def assert_same(suite, task, **kwargs):
    fast, robosuite = trajectory(suite, task, "fast", **kwargs), trajectory(suite, task, "robosuite", **kwargs)
    assert fast[0].shape == robosuite[0].shape and fast[1] == robosuite[1]
    np.testing.assert_array_equal(fast[0], robosuite[0])
    return fast


ACTIONS = np.random.default_rng(0).uniform(-1, 1, size=(40, 7))


@pytest.mark.parametrize("suite", ["libero_object", "libero_spatial", "libero_goal", "libero_10"])
def test_random_actions_give_the_same_states_on_each_suite(suite):
    assert_same(suite, 0, actions=ACTIONS)


@pytest.mark.parametrize(
    "perturbation", ["object", "init", "language", "env", "init@nudge", "object@scale", "env@replace"]
)
def test_random_actions_give_the_same_states_under_each_perturbation(perturbation):
    assert_same("libero_goal", 1, actions=ACTIONS, perturbation=perturbation)


@pytest.mark.parametrize("suite, task", [("libero_goal", 0), ("libero_goal", 7), ("libero_10", 9)])
def test_the_expert_operates_the_articulated_fixtures_alike(suite, task):
    """Drawer, stove knob, microwave door: the expert's episode (its actions read the states, so any
    difference would compound) gives the same states on both paths."""
    states, successes = assert_same(suite, task, expert_steps=160)
    assert len(states) > 20 and np.ptp(states[:, 1:], axis=0).max() > 0.05  # the scene moved


def test_the_paths_can_take_over_from_each_other_mid_episode():
    """The fast path shares robosuite's controller state (goal, cached kinematics, gripper action): handing
    the episode back and forth every 50 steps over 300 steps gives robosuite's own states."""
    actions = np.random.default_rng(1).uniform(-1, 1, size=(300, 7))
    reference = trajectory("libero_goal", 0, "robosuite", actions=actions)[0]
    env = make_env("libero_goal", 0, seed=0, physics="fast", max_steps=10**6)
    try:
        env.reset(seed=3, options={"init_state": 1})
        states = []
        for t, action in enumerate(actions):
            env.physics = ("fast", "robosuite")[(t // 50) % 2]
            env.step(action)
            states.append(env.get_sim_state())
    finally:
        env.close()
    np.testing.assert_array_equal(np.array(states), reference)


def test_a_controller_other_than_liberos_is_refused_in_one_line():
    from types import SimpleNamespace

    from base_suites.arm_control import ArmControl
    from base_suites.runtime import UserInputError

    with pytest.raises(UserInputError, match="physics='robosuite'"):
        ArmControl(SimpleNamespace(controller=object()), model=None)
