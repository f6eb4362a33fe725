"""The goal-relative encoding: the same scene and goal give the same features whatever the task is called
or however its state lists its objects; geometry that moves with an object moves; refusals; and on the
real simulator, every main suite's goals and a LIBERO-PRO variant of a base task."""

from __future__ import annotations

import numpy as np
import pytest
from test_critic_data import ROBOT, goal_geometry

from annotations import GoalFeatureEncoder, encoder_from_dict, make_encoder
from annotations.goal_features import GOAL_SLOTS, OTHER_SLOTS, PREDICATES
from base_suites import make_env
from base_suites.runtime.errors import UserInputError
from base_suites.suites import MAIN_SUITES, list_tasks

ENCODER = GoalFeatureEncoder()
OBJECTS = ("bowl", "plate", "mug", "cup")


def scene(order=OBJECTS, seed: int = 0) -> tuple[list, np.ndarray]:
    """A state of a robot and `order`'s objects, each object's pose fixed by its name (not its place)."""
    layout = ROBOT + [[f"{n}/{part}", size] for n in order for part, size in (("pos", 3), ("quat", 4))]
    rng = np.random.default_rng(seed)
    robot = rng.normal(size=16)
    poses = {n: np.concatenate([rng.normal(size=3), rng.normal(size=4)]) for n in OBJECTS}
    return layout, np.concatenate([robot] + [poses[n] for n in order])


def metadata(layout, geometry, suite="libero_goal", task=8) -> dict:
    return {"suite": suite, "task_index": task, "state_layout": layout, "goal_geometry": geometry}


def on_plate() -> dict:
    return {**goal_geometry(0), "goal": [["on", "bowl", "plate"]], "regions": {}}


def test_the_same_scene_and_goal_encode_alike_under_another_task_name_and_object_order():
    layout, state = scene()
    features = ENCODER.encode(state, ENCODER.check_env(metadata(layout, on_plate())))
    shuffled_layout, shuffled = scene(order=("cup", "plate", "bowl", "mug"))
    again = ENCODER.encode(shuffled, ENCODER.check_env(metadata(shuffled_layout, on_plate(), "libero_90", 41)))
    assert features.shape == (ENCODER.dim,) and features.dtype == np.float32
    np.testing.assert_array_equal(features, again)
    other_goal = {**on_plate(), "goal": [["on", "mug", "plate"]]}
    assert not np.array_equal(features, ENCODER.encode(state, ENCODER.check_env(metadata(layout, other_goal))))


def test_slots_read_the_goal_roles_relative_to_the_end_effector():
    layout, state = scene()
    f = ENCODER.encode(state, ENCODER.check_env(metadata(layout, on_plate())))
    at = {name: 16 + 7 * k for k, name in enumerate(OBJECTS)}
    eef, bowl, plate = state[:3], state[at["bowl"] : at["bowl"] + 3], state[at["plate"] : at["plate"] + 3]
    np.testing.assert_allclose(f[:3], eef - np.array([-0.6, 0.0, 0.9]), rtol=1e-6)
    np.testing.assert_allclose(f[17:20], bowl - eef, rtol=1e-5)  # the object to move
    np.testing.assert_allclose(f[24:27], plate - bowl, rtol=1e-5)  # its destination, from it
    binary = f[ENCODER.state_dim :]
    assert binary[0] == 1 and binary[1 + PREDICATES.index("on")] == 1 and binary[7] == 0  # an object, no region
    assert binary[8:24].sum() == 0  # two empty goal slots
    others = f[17 + 3 * 17 : 17 + 3 * 17 + OTHER_SLOTS * 7].reshape(OTHER_SLOTS, 7)
    distances = [np.linalg.norm(o[:3]) for o in others[:2]]
    assert distances == sorted(distances) and binary[-OTHER_SLOTS:].tolist() == [1, 1, 0, 0, 0]  # mug, cup
    assert sorted(np.round(others[:2, :3] + eef, 5).tolist()) == sorted(
        np.round([state[at[n] : at[n] + 3] for n in ("mug", "cup")], 5).tolist()
    )


def test_a_region_riding_on_an_object_moves_with_it_and_an_articulation_reports_progress():
    layout, state = scene()
    geometry = {
        **on_plate(),
        "goal": [["in", "mug", "bowl_inside"], ["close", "cabinet_top"]],
        "regions": {
            "bowl_inside": {"frame": "object", "parent": "bowl", "position": [0, 0, 0.1], "half_size": [0.1] * 3},
            "cabinet_top": {"frame": "world", "parent": "cabinet", "position": [0.5, 0, 1.0], "half_size": None},
        },
        "articulations": {"close(cabinet_top)": {"entity": "cabinet", "index": 1, "reference": -0.15, "goal": 0.0}},
    }
    layout = layout + [["cabinet/joints", 2]]
    context = ENCODER.check_env(metadata(layout, geometry))
    bowl = 16 + 7 * OBJECTS.index("bowl")
    state = np.concatenate([state, [0.3, -0.075]])
    state[bowl + 3 : bowl + 7] = [0, 0, 0, 1]  # upright: the region sits 0.1 above the bowl
    f = ENCODER.encode(state, context)
    mug = state[16 + 7 * 2 : 16 + 7 * 2 + 3]
    np.testing.assert_allclose(f[24:27] + mug, state[bowl : bowl + 3] + [0, 0, 0.1], atol=1e-6)
    state[bowl + 3 : bowl + 7] = [1, 0, 0, 0]  # turned upside down about x: the region is now below it
    f_flipped = ENCODER.encode(state, context)
    np.testing.assert_allclose(f_flipped[24:27] + mug, state[bowl : bowl + 3] - [0, 0, 0.1], atol=1e-6)
    assert f[34 + 16] == pytest.approx(0.5)  # the drawer halfway from open (-0.15) to closed (0)
    np.testing.assert_allclose(f[34 : 34 + 3], np.array([0.5, 0, 1.0]) - state[:3], rtol=1e-6)


def test_batches_encode_like_single_states():
    layout, state = scene()
    context = ENCODER.check_env(metadata(layout, on_plate()))
    batch = np.stack([scene(seed=s)[1] for s in range(5)])
    np.testing.assert_array_equal(ENCODER.encode(batch, context)[3], ENCODER.encode(batch[3], context))


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda g: None, "has no goal_geometry"),
        (lambda g: {"error": "goal predicate ['up', 'x'] is not one of"}, "cannot encode its goal: goal predicate"),
        (lambda g: {**g, "version": 2}, "goal_geometry version 2"),
        (
            lambda g: {**g, "goal": [["on", "bowl", "plate"]] * (GOAL_SLOTS + 1)},
            "4 goal predicates; the encoding holds 3",
        ),
        (lambda g: {**g, "goal": [["on", "vase", "plate"]]}, "its goal names 'vase', whose pose its state does not"),
        (lambda g: {**g, "goal": [["stack", "bowl", "plate"]]}, "goal predicate 'stack' is not one of"),
    ],
)
def test_refusals_name_the_env_and_the_reason(change, message):
    layout, _ = scene()
    with pytest.raises(UserInputError, match=message):
        ENCODER.check_env(metadata(layout, change(on_plate())), "critic/")


def test_a_state_of_another_width_and_the_encoders_round_trip():
    layout, state = scene()
    context = ENCODER.check_env(metadata(layout, on_plate()))
    with pytest.raises(UserInputError, match="state has 43 entries; its layout has 44"):
        ENCODER.encode(state[:-1], context)
    saved = make_encoder("goal-relative", {"libero_goal/8": layout}).to_dict()
    assert saved == {"kind": "goal-relative", "version": 1, "tasks": ["libero_goal/8"]}
    assert isinstance(encoder_from_dict(saved), GoalFeatureEncoder)
    assert type(encoder_from_dict({"layouts": {"t/0": layout}})).__name__ == "TaskFeatureEncoder"
    with pytest.raises(UserInputError, match="unknown encoding 'pixels'"):
        make_encoder("pixels", {"t/0": layout})


def test_every_main_suite_goal_fits_the_encoding():
    """Without a simulator: every goal of the five LIBERO suites uses the predicates and slots it has."""
    for suite in MAIN_SUITES:
        for task in list_tasks(suite):
            assert len(task.goal) <= GOAL_SLOTS and {p[0] for p in task.goal} <= set(PREDICATES), (suite, task)


@pytest.mark.parametrize("suite, task", [("libero_spatial", 3), ("libero_10", 9), ("libero_goal", 0), ("libero_90", 5)])
def test_real_envs_record_a_geometry_the_encoding_reads(suite, task):
    env = make_env(suite, task)
    try:
        obs, _ = env.reset(seed=3, options={"init_state": 1})
        features = ENCODER.encode(obs["state"], ENCODER.check_env(env.metadata))
        assert np.isfinite(features).all()
        assert features[ENCODER.state_dim :: 8][: len(env.task.goal)].tolist() == [1.0] * len(env.task.goal)
    finally:
        env.close()


def test_a_pro_language_variant_encodes_its_base_task_state_alike():
    """LIBERO-PRO's paraphrase of libero_object/2 is the same scene and goal: the base task's state, fixtures
    and all, gives the same features in the variant, so a model trained on the base task reads it."""
    features, instructions, scene_state = [], [], None
    for suite in ("libero_object", "libero_object_lan"):
        env = make_env(suite, 2)
        try:
            obs, _ = env.reset(seed=5, options={"init_state": 4})
            if scene_state is None:
                scene_state = env.get_sim_state(), env.fixture_layout()
            else:
                env.set_fixture_layout(scene_state[1])
                obs = env.set_sim_state(scene_state[0])
            metadata = {**env.metadata, "goal_geometry": env.goal_geometry()}
            instructions.append(env.instruction)
            features.append(ENCODER.encode(obs["state"], ENCODER.check_env(metadata)))
        finally:
            env.close()
    assert instructions[0] != instructions[1]  # the paraphrase: another task to a task one-hot
    np.testing.assert_array_equal(features[0], features[1])


def test_robustness_preflight_refuses_a_task_onehot_critic_on_variants_and_passes_a_goal_relative_one(tmp_path):
    from test_critic_data import write_annotated
    from test_critic_train import UNIT

    from critics import train_critic
    from elegant.evaluation.robustness import _refuse_unreadable_axes

    data = write_annotated(tmp_path / "train.hdf5")
    plan = {"libero_object": {"object": ["libero_object_object/0"]}}
    for encoding in ("task-onehot", "goal-relative"):
        out = str(tmp_path / encoding)
        train_critic([data], out, steps=1, config=UNIT, encoding=encoding, progress=False)
        if encoding == "task-onehot":
            with pytest.raises(UserInputError, match="trained on libero_object/0, libero_object/1; the object"):
                _refuse_unreadable_axes(None, out, plan)
        else:
            _refuse_unreadable_axes(None, out, plan)


def test_a_goal_relative_bc_policy_acts_in_a_task_it_never_saw_and_its_film_reads_the_goal(tmp_path):
    from test_critic_data import task_layout, write_annotated

    from elegant.policies import load_policy
    from elegant.policies.bc_train import train_policy

    data = write_annotated(tmp_path / "demos.hdf5")
    tiny = {"epochs": 1, "hidden": (16,), "modes": 2, "history": 2, "chunk": 2, "progress": False}
    out = str(tmp_path / "goal_policy")
    train_policy([data], out, encoding="goal-relative", successful_only=False, **tiny)
    policy = load_policy(out)
    assert policy.config["model"]["task_dim"] == ENCODER.dim - ENCODER.state_dim  # the goal's structure
    layout = task_layout(2)
    unseen = {"suite": "libero_goal", "task_index": 5, "state_layout": layout, "goal_geometry": goal_geometry(1)}
    policy.reset(unseen, seed=0)
    state = np.random.default_rng(0).normal(size=sum(s for _, s in layout))
    action = policy({"state": state})
    assert action.shape == (7,) and np.isfinite(action).all()
    policy.reset(seed=0)
    with pytest.raises(UserInputError, match="needs reset\\(env.metadata\\)"):
        policy({"state": state})
    onehot = str(tmp_path / "onehot_policy")
    train_policy([data], onehot, successful_only=False, **tiny)
    with pytest.raises(UserInputError, match="'libero_goal/5' is not among the tasks"):
        load_policy(onehot).reset(unseen)


def test_an_ensemble_of_goal_relative_critics_encodes_each_state_once_and_scores_as_its_members(tmp_path, monkeypatch):
    from test_critic_data import task_layout, write_annotated
    from test_critic_train import UNIT

    from critics import load, load_ensemble, train_critic

    data = write_annotated(tmp_path / "train.hdf5")
    dirs = [str(tmp_path / f"member_{k}") for k in (0, 1)]
    for k, out in enumerate(dirs):
        train_critic([data], out, steps=2, config=UNIT, encoding="goal-relative", bootstrap=k, progress=False)
    layout = task_layout(2)
    unseen = {"suite": "libero_goal", "task_index": 5, "state_layout": layout, "goal_geometry": goal_geometry(1)}
    rng = np.random.default_rng(2)
    state, actions = rng.normal(size=sum(s for _, s in layout)), rng.uniform(-0.5, 0.5, size=(3, 7))
    alone = np.stack([load(d).bind(unseen).q(state, actions) for d in dirs])
    ensemble = load_ensemble(dirs).bind(unseen)
    assert ensemble.members[0].context is ensemble.members[1].context
    calls = []
    original = GoalFeatureEncoder._encode
    monkeypatch.setattr(GoalFeatureEncoder, "_encode", lambda self, s, c: calls.append(1) or original(self, s, c))
    np.testing.assert_array_equal(ensemble.member_q(state, actions), alone)
    assert len(calls) == 1
    ensemble.member_q(state + 0.1, actions)
    assert len(calls) == 2
