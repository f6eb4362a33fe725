"""The start check (`base_suites.start_check`) on the real simulator: the starts that LIBERO's own physics
keeps stand on the default stack (libero_spatial/5's bowl stays on its ramekin, libero_10/0's bottles stay
on the table), and a start made to break is named with how."""

from __future__ import annotations

import pytest

from base_suites import make_env
from base_suites.start_check import check_start

pytestmark = pytest.mark.sim


@pytest.mark.parametrize("suite, task, init", [("libero_spatial", 5, 0), ("libero_10", 0, 0), ("libero_object", 0, 3)])
def test_shipped_starts_that_libero_keeps_stand_on_the_default_stack(suite, task, init):
    env = make_env(suite, task, seed=0, settle_steps=0)
    try:
        assert check_start(env, init) == []
    finally:
        env.close()


def test_a_start_with_an_object_off_the_table_is_named_with_how_it_broke():
    """The plate of libero_spatial/5 put 1 m to the side of its place in the shipped state: after the settle steps
    it lies on the floor, away from its region; the rest of the start still stands."""
    env = make_env("libero_spatial", 5, seed=0, settle_steps=0)
    try:
        address = env.domain.sim.model.get_joint_qpos_addr(env.domain.get_object("plate_1").joints[0])[0]
        states = env._init_states.copy()
        states[1, 2 + address] += 1.0  # the flattened state is (time, qpos, qvel): y of the plate's free joint
        env._init_states = states
        broken = [str(b) for b in check_start(env, 1)]
        assert any(b.startswith("plate_1: fell off the table") for b in broken), broken
        assert any(b.startswith("plate_1: left main_table_plate_region by") for b in broken), broken
        assert all(b.startswith("plate_1") for b in broken), broken
        assert check_start(env, 0) == []
    finally:
        env.close()


def test_the_check_refuses_an_env_that_settles_by_itself():
    env = make_env("libero_object", 0, seed=0, settle_steps=2)
    try:
        with pytest.raises(ValueError, match="settle_steps=0"):
            check_start(env, 0)
    finally:
        env.close()
