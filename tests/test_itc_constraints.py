"""The four ITCs on the real simulator: for each, a scripted execution that keeps it and one that breaks it.

One libero_goal scene (bowl, cream cheese, wine bottle, plate, cabinet, stove, rack) serves every test;
its tasks differ only in the goal, so each test picks the task whose spec fits (cream cheese into the
bowl, bowl onto the plate, wine bottle onto the cabinet). The end effector is driven by a proportional
controller on `env.sim.eef_position()`; sub-goal order and idle fixtures are exercised by jumping to
modified MuJoCo states.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from base_suites import get_task, make_env
from itc import CRITERIA, ITCMonitor, ITCParams, ITCWrapper, derive_spec

pytestmark = pytest.mark.sim

SCENE = "libero_goal"
CHEESE_INTO_BOWL, BOWL_ONTO_PLATE, BOTTLE_ONTO_CABINET, OPEN_MIDDLE_DRAWER = 6, 8, 2, 0
OPEN, CLOSE = -1.0, 1.0  # gripper commands


class Scripted:
    """Drives the end effector to points and records every step (monitor results, demo arrays)."""

    def __init__(self, env, monitor: ITCMonitor | None = None) -> None:
        self.env, self.sim, self.monitor = env, env.sim, monitor
        self.results, self.actions, self.states, self.obs, self.next_obs, self.rewards = [], [], [], [], [], []
        self.success = False

    def step(self, action: np.ndarray) -> None:
        if self.success:  # LIBERO's episode ends at success
            return
        self.states.append(self.env.get_sim_state())
        self.obs.append(self.env.state_vector())
        obs, reward, terminated, _, info = self.env.step(action)
        self.actions.append(np.asarray(action, dtype=float))
        self.next_obs.append(obs["state"])
        self.rewards.append(reward)
        self.success = bool(info["success"])
        if self.monitor is not None:
            self.results.append(self.monitor.step(action))

    def move(self, target, grip: float, steps: int = 60, gain: float = 10.0, tol: float = 0.004, rot=None) -> None:
        for _ in range(steps):
            error = np.asarray(target, dtype=float) - self.sim.eef_position()
            action = np.zeros(7)
            action[:3] = np.clip(gain * error, -1, 1)
            action[6] = grip
            if rot is not None:
                action[3:6] = rot
            self.step(action)
            if rot is None and np.linalg.norm(error) < tol:
                break

    def wait(self, grip: float, steps: int) -> None:
        for _ in range(steps):
            self.step(np.r_[np.zeros(6), grip])

    def grasp(self, obj: str, height: float = 0.0, lift: float = 0.10) -> None:
        """Top-down grasp at `height` above the object's origin, then lift."""
        at = self.sim.position(obj) + [0, 0, height]
        self.move(at + [0, 0, 0.08], OPEN)
        self.move(at, OPEN, steps=40)
        self.wait(CLOSE, 10)
        self.move(self.sim.eef_position() + [0, 0, lift], CLOSE)

    def place(self, at, release_height: float) -> None:
        """Carry the held object above `at`, lower it to `release_height` above `at`, open, retreat."""
        at = np.asarray(at, dtype=float)
        self.move(at + [0, 0, 0.15], CLOSE, steps=80)
        self.move(at + [0, 0, release_height], CLOSE)
        self.wait(OPEN, 15)
        self.move(self.sim.eef_position() + [0, 0, 0.08], OPEN, steps=30)

    def reasons(self, criterion: str) -> list[str]:
        return [r for res in self.results for r in res.reasons[criterion]]

    def violated(self) -> set[str]:
        return {c for c in CRITERIA if self.reasons(c)}


@pytest.fixture(scope="module")
def env():
    env = make_env(SCENE, CHEESE_INTO_BOWL, init_state=0, seed=0)
    yield env
    env.close()


def start(env, task: int, spec=None) -> Scripted:
    env.reset(options={"init_state": 0})
    monitor = ITCMonitor(env, spec=spec or derive_spec(get_task(SCENE, task)))
    monitor.reset()
    return Scripted(env, monitor)


# ---- the clean reference: every criterion kept ------------------------------------------------
def test_clean_pick_and_place_keeps_every_criterion(env):
    run = start(env, CHEESE_INTO_BOWL)
    run.grasp("cream_cheese_1")
    assert env.sim.held_object() == "cream_cheese_1"
    run.place(env.sim.position("akita_black_bowl_1"), release_height=0.06)
    verdict = run.monitor.verdict(run.success)
    assert run.success, "the scripted placement should solve the task"
    assert verdict.violated == [] and verdict.elegant, verdict.events
    assert all(r.reward == 1.0 for r in run.results)


# ---- pose accuracy ----------------------------------------------------------------------------
def test_placing_beside_the_target_violates_pose_accuracy(env):
    run = start(env, CHEESE_INTO_BOWL)
    run.grasp("cream_cheese_1")
    # beside the bowl on the side away from the plate, which a held cheese would press
    run.place(env.sim.position("akita_black_bowl_1") + [0, 0.10, 0], release_height=0.025)
    run.wait(OPEN, 5)
    assert not run.success
    assert run.violated() == {"pose_accuracy"}
    (reason,) = run.reasons("pose_accuracy")
    assert "cream_cheese_1 placed on akita_black_bowl_1" in reason and "allowed 3.0 cm" in reason


# ---- collision --------------------------------------------------------------------------------
def test_dropping_from_height_violates_collision(env):
    run = start(env, CHEESE_INTO_BOWL)
    run.grasp("cream_cheese_1", lift=0.15)
    run.wait(OPEN, 20)
    reasons = run.reasons("collision")
    assert any(r.startswith("dropped cream_cheese_1") for r in reasons), reasons
    assert any("cream_cheese_1 hit table at" in r for r in reasons), reasons
    drop_step = next(res.step for res in run.results if not res.kept["collision"])
    assert all(res.kept["collision"] for res in run.results[:drop_step]), "no collision while grasping and lifting"


def test_a_success_reached_by_dropping_from_height_is_not_an_elegant_success(env):
    """The cheese released 12 cm above the bowl still lands in it: LIBERO counts a success, the drop
    violates collision, and an elegant success needs both."""
    run = start(env, CHEESE_INTO_BOWL)
    run.grasp("cream_cheese_1", lift=0.15)
    run.place(env.sim.position("akita_black_bowl_1"), release_height=0.12)
    verdict = run.monitor.verdict(run.success)
    assert run.success and verdict.success, "the dropped cheese should land in the bowl"
    assert "collision" in verdict.violated and not verdict.elegant
    assert verdict.to_dict()["elegant"] is False


def test_pushing_a_distractor_violates_sequence_and_collision(env):
    run = start(env, BOWL_ONTO_PLATE)  # the cream cheese is a distractor of this task
    cheese = env.sim.position("cream_cheese_1")
    run.move(cheese + [-0.08, 0, 0.10], CLOSE)
    run.move(cheese + [-0.08, 0, 0.02], CLOSE, steps=40)
    assert run.violated() == set(), "approaching without touching keeps everything"
    run.move(cheese + [0.06, 0, 0.02], CLOSE, steps=30)
    assert any(r.startswith("disturbed cream_cheese_1: moved") for r in run.reasons("sequence"))
    assert any(r.startswith("gripper pressed cream_cheese_1 with") for r in run.reasons("collision"))


def test_a_sliding_push_violates_collision_whatever_the_contact_force(env):
    """A finger sliding a light box along the table loads the contact only now and then; the moving
    object in contact with the robot is what gives the push away (`push_speed`)."""

    def push(params: ITCParams) -> Scripted:
        env.reset(options={"init_state": 0})
        monitor = ITCMonitor(env, spec=derive_spec(get_task(SCENE, BOWL_ONTO_PLATE)), params=params)
        monitor.reset()
        run = Scripted(env, monitor)
        cheese = env.sim.position("cream_cheese_1")
        run.move(cheese + [-0.08, 0, 0.10], CLOSE)
        run.move(cheese + [-0.08, 0, 0.02], CLOSE, steps=40)
        run.move(cheese + [0.06, 0, 0.02], CLOSE, steps=30)
        return run

    no_force_limit = push(ITCParams(contact_force=1e3))
    assert any(r.startswith("gripper pushed cream_cheese_1 at") for r in no_force_limit.reasons("collision"))
    neither = push(ITCParams(contact_force=1e3, push_speed=1e3))
    assert neither.reasons("collision") == []


# ---- alignment --------------------------------------------------------------------------------
def test_carrying_an_upright_bottle_tilted_violates_alignment(env):
    run = start(env, BOTTLE_ONTO_CABINET)
    run.grasp("wine_bottle_1", height=0.13, lift=0.08)
    assert env.sim.held_object() == "wine_bottle_1"
    assert run.violated() == set(), "a top-down grasp and an upright lift keep every criterion"
    run.move(env.sim.eef_position(), CLOSE, steps=15, rot=np.array([0.5, 0.0, 0.0]))
    reasons = run.reasons("alignment")
    assert reasons and all(r.startswith("carrying wine_bottle_1 tilted") for r in reasons), reasons


def test_knocking_a_bottle_over_violates_alignment(env):
    run = start(env, BOWL_ONTO_PLATE)
    bottle = env.sim.position("wine_bottle_1")
    run.move(bottle + [0, 0.12, 0.25], CLOSE)
    run.move(bottle + [0, 0.12, 0.12], CLOSE)
    run.move(bottle + [0, -0.15, 0.12], CLOSE, steps=30, gain=30.0)
    run.wait(CLOSE, 10)
    assert any(r.startswith("wine_bottle_1 tipped over to") for r in run.reasons("alignment"))
    assert any(r.startswith("disturbed wine_bottle_1") for r in run.reasons("sequence"))


# ---- sequence: sub-goal order, undoing, fixtures the task does not name -----------------------
def _with_joint(env, joint: str, value: float) -> np.ndarray:
    model = env.domain.sim.model._model
    state = env.get_sim_state()
    state[1 + model.jnt_qposadr[model.joint(joint).id]] = value
    return state


def test_sub_goal_order_and_undoing(env):
    top, middle = ("open", "wooden_cabinet_1_top_region"), ("open", "wooden_cabinet_1_middle_region")
    spec = dataclasses.replace(
        derive_spec(get_task(SCENE, OPEN_MIDDLE_DRAWER)), subgoals=(middle, top), order=((0, 1),)
    )

    def run_order(first: str, second: str) -> list[str]:
        env.reset(options={"init_state": 0})
        monitor = ITCMonitor(env, spec=spec)
        monitor.reset()
        reasons = []
        for joint in (first, second):
            env.set_sim_state(_with_joint(env, joint, -0.16))
            reasons += monitor.step().reasons["sequence"]
        assert env.sim.predicate(top) and env.sim.predicate(middle)
        return reasons

    assert run_order("wooden_cabinet_1_middle_level", "wooden_cabinet_1_top_level") == []
    wrong = run_order("wooden_cabinet_1_top_level", "wooden_cabinet_1_middle_level")
    assert wrong == ["reached open(wooden_cabinet_1_top_region) before open(wooden_cabinet_1_middle_region)"]

    env.reset(options={"init_state": 0})
    monitor = ITCMonitor(env, spec=spec)
    monitor.reset()
    env.set_sim_state(_with_joint(env, "wooden_cabinet_1_middle_level", -0.16))
    assert monitor.step().kept["sequence"]
    env.set_sim_state(_with_joint(env, "wooden_cabinet_1_middle_level", 0.0))
    flags = [monitor.step().kept["sequence"] for _ in range(monitor.params.undo_grace_steps)]
    assert flags == [True] * (monitor.params.undo_grace_steps - 1) + [False]


def test_turning_an_unnamed_knob_violates_sequence(env):
    env.reset(options={"init_state": 0})
    monitor = ITCMonitor(env, spec=derive_spec(get_task(SCENE, CHEESE_INTO_BOWL)))
    monitor.reset()
    assert "flat_stove_1" in monitor.spec.idle_fixtures
    env.set_sim_state(_with_joint(env, "flat_stove_1_button", 0.1))
    assert monitor.step().kept["sequence"], "a small knob wiggle is within the hinge tolerance"
    env.set_sim_state(_with_joint(env, "flat_stove_1_button", 0.8))
    result = monitor.step()
    assert result.reasons["sequence"][0].startswith("moved flat_stove_1, which the task does not name")


def test_objects_still_settling_at_reset_are_no_false_alarm():
    """libero_object/0 after one settle step: the shipped objects start inside the floor, pop out and are
    still moving when the episode starts; they must be judged from where they come to rest, not from where
    they were at reset."""
    env = make_env("libero_object", 0, init_state=0, seed=0, settle_steps=1)
    try:
        assert max(float(np.linalg.norm(env.sim.velocity(o))) for o in env.sim.objects) > 0.5
        monitor = ITCMonitor(env)
        monitor.reset()
        run = Scripted(env, monitor)
        run.wait(OPEN, 20)
        assert run.violated() == set()
        pushed = monitor.spec.distractors[0]
        state = env.get_sim_state()
        model = env.domain.sim.model._model
        state[1 + model.jnt_qposadr[model.joint(env.domain.get_object(pushed).joints[0]).id]] += 0.05
        env.set_sim_state(state)
        assert monitor.step().reasons["sequence"][0].startswith(f"disturbed {pushed}: moved 5.0 cm")
    finally:
        env.close()


# ---- monitor and wrapper API ------------------------------------------------------------------
def test_wrapper_reports_flags_reward_and_final_verdict(env):
    wrapped = ITCWrapper(env)
    old_max = env.max_steps
    env.max_steps = 4
    try:
        wrapped.reset(options={"init_state": 0})
        for _ in range(4):
            _, _, terminated, truncated, info = wrapped.step(np.r_[np.zeros(6), OPEN])
            assert info["itc"]["kept"] == {c: True for c in CRITERIA} and info["elegance_reward"] == 1.0
            assert ("itc_verdict" in info) == (terminated or truncated)
    finally:
        env.max_steps = old_max
    verdict = info["itc_verdict"]
    assert truncated and verdict["success"] is False and verdict["elegant"] is False and verdict["violated"] == []
    assert verdict["segments"] == {c: [True] for c in CRITERIA}


def test_a_violation_on_a_window_boundary_marks_the_second_25_frame_window_only(env):
    """Steps 0-24 are the first window and 25-49 the second: a distractor knocked at step 25 leaves the
    first window kept, and 50 steps make exactly two windows (a monitor cutting 24-frame windows makes three)."""
    run = start(env, BOWL_ONTO_PLATE)  # the cream cheese is a distractor of this task
    run.wait(OPEN, 25)
    state = env.get_sim_state()
    model = env.domain.sim.model._model
    state[1 + model.jnt_qposadr[model.joint(env.domain.get_object("cream_cheese_1").joints[0]).id]] += 0.05
    env.set_sim_state(state)
    run.wait(OPEN, 25)
    assert [r.kept["sequence"] for r in run.results].index(False) == 25
    verdict = run.monitor.verdict(run.success)
    assert verdict.segment_length == 25
    assert {c: len(verdict.segments[c]) for c in CRITERIA} == {c: 2 for c in CRITERIA}
    assert verdict.segments["sequence"].tolist() == [True, False] and "sequence" in verdict.violated


def test_monitor_refuses_steps_before_reset(env):
    with pytest.raises(RuntimeError, match="reset"):
        ITCMonitor(env).step()


def test_goal_objects_sharing_one_region_get_its_half_size_as_tolerance():
    """libero_10/0 puts two objects in one basket: they cannot both sit at its centre, so each may lie
    within the region's half size minus the edge margin (4.1 cm per axis), not the single-object 3 cm that
    libero_object/0's one object in its basket gets."""
    from itc.context import StepContext

    tolerances = {}
    for suite in ("libero_10", "libero_object"):
        env = make_env(suite, 0, init_state=0, seed=0)
        try:
            monitor = ITCMonitor(env)
            pose = next(c for c in monitor.constraints if c.name == "pose_accuracy")
            pose.reset(StepContext(env.sim))
            tolerances[suite] = [pose._centre(StepContext(env.sim), p)[2] for p in monitor.spec.placements]
        finally:
            env.close()
    assert len(tolerances["libero_10"]) == 2 and len(tolerances["libero_object"]) == 1
    for tol in tolerances["libero_10"]:
        np.testing.assert_allclose(tol, [0.041, 0.041], atol=5e-4)
    np.testing.assert_allclose(tolerances["libero_object"][0], [0.03, 0.03])


def test_an_object_standing_where_the_goal_object_goes_may_be_moved_but_others_not():
    """libero_goal/5 ("push the plate to the front of the stove"): the cream cheese lies where the wide
    plate will stand, so moving it is in the way of the task, not a disturbance; the wine bottle, away
    from the stove, is a distractor whose 5 cm move is."""
    env = make_env(SCENE, 5, init_state=8, seed=0)
    try:
        monitor = ITCMonitor(env)
        monitor.reset()
        Scripted(env, monitor).wait(OPEN, 20)  # the distractors come to rest and are anchored
        model = env.domain.sim.model._model

        def shift(name: str) -> list[str]:
            state = env.get_sim_state()
            state[1 + model.jnt_qposadr[model.joint(env.domain.get_object(name).joints[0]).id]] += 0.05
            env.set_sim_state(state)
            return monitor.step().reasons.get("sequence", [])

        assert shift("cream_cheese_1") == []
        assert shift("wine_bottle_1")[0].startswith("disturbed wine_bottle_1: moved 5.0 cm")
    finally:
        env.close()
