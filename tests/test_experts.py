"""Scripted experts and demo collection on the real simulator (one task per primitive family)."""

import h5py
import numpy as np
import pytest
from conftest import interrupted_at_second_episode
from scipy.spatial import ConvexHull, Delaunay

import annotations.collect as collect
from annotations import DemoFile
from base_suites import UserInputError, make_env
from base_suites.experts import ScriptedExpert, articulated, plan_skills, skills
from base_suites.experts.control import finger_axis
from base_suites.experts.geometry import (
    REACH_LIMIT,
    YAWS,
    _rim_grasps,
    choose_grasp,
    fill_boxes,
    headroom,
    shape_of,
    slide_path,
    standing_points,
    way_out,
)
from base_suites.experts.skills import SkillContext
from itc import ITCWrapper

pytestmark = pytest.mark.sim


def _solve(suite, task, init=0, quality="clean", episode=0, reset_seed=None):
    """Run the expert for one episode under the ITC monitor; returns (success, expert, ITC verdict)."""
    env = ITCWrapper(make_env(suite, task, seed=0))
    obs, _ = env.reset(seed=reset_seed, options={"init_state": init})
    expert = ScriptedExpert(env.unwrapped, quality=quality, seed=0)
    expert.reset(env.unwrapped.metadata, episode=episode)
    info = {"success": False}
    for _ in range(env.unwrapped.max_steps):
        obs, _, terminated, truncated, info = env.step(expert(obs))
        if terminated or truncated:
            break
    env.close()
    return info["success"], expert, info.get("itc_verdict", {})


@pytest.mark.parametrize(
    "suite, task, family",
    [
        ("libero_goal", 0, "open drawer"),
        ("libero_goal", 7, "turn knob"),
        ("libero_spatial", 0, "pick and place (rim grasp of a bowl)"),
        ("libero_spatial", 4, "pick from an open drawer, carry over the cabinet"),
        ("libero_goal", 9, "set down on a tilted shelf (the wine rack)"),
        ("libero_goal", 3, "open a drawer, pick from under it and carry out sideways, place into it"),
        ("libero_10", 3, "pull a partly open drawer out, fit a bowl under the drawer above, push it shut"),
    ],
)
def test_expert_solves_one_task_per_primitive_family(suite, task, family):
    success, _, verdict = _solve(suite, task)
    assert success, family
    # clean means elegant too: the drawer pull once tipped the bowl and pressed the plate in front of it
    assert verdict["violated"] == [], (family, verdict["events"][:3])


def test_a_plate_is_pushed_around_the_cream_cheese_into_its_region():
    """libero_goal/5 ("push the plate to the front of the stove"): the cream cheese lies beside that spot,
    across the straight line from the plate. The push goes around it and the plate ends in its region
    with the cheese untouched; the fingertips press the plate's floor, which is no grasp."""
    env = ITCWrapper(make_env("libero_goal", 5, seed=0))
    obs, _ = env.reset(options={"init_state": 0})
    view = env.unwrapped.sim
    cheese = view.position("cream_cheese_1").copy()
    path = slide_path(view, "plate_1", skills.target_xy(view, "main_table_stove_front_region", held="plate_1"))
    assert len(path) > 1  # not the straight line through the cheese
    expert = ScriptedExpert(env.unwrapped, quality="clean", seed=0)
    expert.reset(env.unwrapped.metadata, episode=0)
    info, held = {}, set()
    for _ in range(env.unwrapped.max_steps):
        obs, _, terminated, truncated, info = env.step(expert(obs))
        held.add(view.held_object())
        if terminated or truncated:
            break
    moved = float(np.linalg.norm(view.position("cream_cheese_1") - cheese))
    env.close()
    assert info["success"] and moved < 0.005, moved
    assert held == {None}
    assert info["itc_verdict"]["violated"] == [], info["itc_verdict"]["events"][:3]


def test_a_mug_goes_into_the_microwave_through_its_doorway():
    """libero_10/9 ("put the mug in the microwave and close it"): the heating region has a roof, so a
    top-down carry set the mug on top of the microwave. The doorway faces the shut door's normal; the
    mug is held by its handle, turned to trail it outward, and slid in below the roof, the hand staying
    outside; the door is then swung shut from behind its edge."""
    env = make_env("libero_10", 9, seed=0)
    env.reset(options={"init_state": 0})
    facing, front = articulated.doorway(env.sim, "microwave_1_heating_region")
    assert np.allclose(facing, [0.0, -1.0, 0.0], atol=1e-6) and abs(front + 0.268) < 0.005, (facing, front)
    assert articulated.doorway(env.sim, "kitchen_table_porcelain_mug_front_region") is None  # on the table: from above
    env.close()
    stove = make_env("libero_goal", 1, seed=0)  # a burner has a hinged knob but no roof: reached from above
    stove.reset(options={"init_state": 0})
    assert articulated.doorway(stove.sim, "flat_stove_1_cook_region") is None
    stove.close()
    success, _, verdict = _solve("libero_10", 9)
    assert success
    assert not {"collision", "sequence"} & set(verdict["violated"]), verdict["events"][:3]


def test_an_object_the_opened_drawer_would_hang_over_is_moved_clear_only_if_no_grasp_stays_reachable():
    """libero_goal/3: the bowl stands where the top drawer will hang over it. At init 0 enough of its rim
    will stick out for a rim grasp, so the plan opens the drawer first; at init 20 every grasp would
    bring the hand into the opened drawer, so the bowl is first moved clear of it."""
    env = make_env("libero_goal", 3, seed=0)
    view, drawer, bowl = env.sim, "wooden_cabinet_1_top_region", "akita_black_bowl_1"
    env.reset(options={"init_state": 0})
    assert [pred for pred, _ in plan_skills(env.task.goal, view)] == [("open", drawer), ("in", bowl, drawer)]
    env.reset(options={"init_state": 20})
    assert [pred for pred, _ in plan_skills(env.task.goal, view)] == [
        ("clear", bowl, drawer),
        ("open", drawer),
        ("in", bowl, drawer),
    ]
    lo, hi = articulated.opened_footprint(view, drawer)
    spot = articulated.clear_spot(view, drawer, bowl)
    moved = view.geom_points(bowl)[:, :2] - view.position(bowl)[:2] + spot
    assert np.any((moved < lo) | (moved > hi), axis=1).all()  # every point of the bowl outside the drawer box
    # the drawer of libero_goal/0 (nothing to put in it) plans no clearing
    env0 = make_env("libero_goal", 0, seed=0)
    env0.reset(options={"init_state": 0})
    assert all(pred[0] != "clear" for pred, _ in plan_skills(env0.task.goal, env0.sim))
    env.close()
    env0.close()


def test_a_bowl_moved_clear_of_the_drawer_still_goes_in_within_the_horizon():
    """libero_goal/3 init 20: the bowl must first be moved clear of where the drawer will stand, then
    the drawer opened, then the bowl picked again and put in, all within LIBERO's 300 steps. The
    clearing carry low over the table (~80 steps), the short turn to the handle's nearer grip and the
    tilt back down while backing off (~100 steps for the opening) make it fit; before them the episode
    took 330-380 steps."""
    env = make_env("libero_goal", 3, seed=0)
    env.reset(options={"init_state": 20})
    assert [pred[0] for pred, _ in plan_skills(env.task.goal, env.sim)][0] == "clear"
    env.close()
    success, _, _ = _solve("libero_goal", 3, init=20)
    assert success


def test_an_object_lifted_under_the_opened_drawer_has_a_way_out_sideways():
    """With the drawer open over it, the bowl may rise only to just under the drawer's bottom; shifted
    by `way_out`, nothing hangs over it any more and it can rise to any carrying height."""
    env = make_env("libero_goal", 3, seed=0)
    env.reset(options={"init_state": 0})
    view, bowl, domain = env.sim, "akita_black_bowl_1", env.domain
    assert headroom(view, bowl, 0.0) == np.inf  # nothing over it while the drawer is shut
    cabinet_joint = domain.object_sites_dict["wooden_cabinet_1_top_region"].joints[0]
    domain.sim.data.set_joint_qpos(cabinet_joint, view.open_position("wooden_cabinet_1") - 0.01)
    bowl_joint = domain.get_object(bowl).joints[0]

    def move_bowl(shift):
        pose = domain.sim.data.get_joint_qpos(bowl_joint).copy()
        pose[:3] += shift
        domain.sim.data.set_joint_qpos(bowl_joint, pose)
        domain.sim.forward()

    move_bowl([0.0, 0.0, 0.05])
    room = headroom(view, bowl, 0.0)
    assert 0.0 < room < 0.06  # the drawer's bottom is ~10 cm above the bowl's rim on the table
    shift = way_out(view, bowl, 0.0)
    assert shift is not None and 0.0 < np.linalg.norm(shift) <= 0.10
    move_bowl([*shift, 0.0])
    assert headroom(view, bowl, 0.0) == np.inf
    env.close()


def _run_skill(env, skill, max_steps: int = 400) -> tuple[bool, set[str]]:
    """Step one skill to its end; returns its result and what the robot touched on the way."""
    touched = set()
    try:
        for _ in range(max_steps):
            env.step(next(skill))
            touched |= {c.other("robot") for c in env.sim.contacts() if c.involves("robot")}
    except StopIteration as done:
        return bool(done.value), touched
    raise AssertionError(f"the skill did not finish in {max_steps} steps")


def test_a_rim_grasp_leaves_the_arm_the_reach_to_set_the_bowl_down():
    """libero_spatial/4 (reset seed 8, init 2): the clearest rim grasp of the bowl in the drawer is on
    its far side; carried to the plate, that hand sat 76 cm from the robot base, the elbow locked
    straight and the set-down stalled. Told where the bowl goes, the grasp keeps the hand within reach."""
    env = make_env("libero_spatial", 4, seed=0)
    env.reset(seed=8, options={"init_state": 2})
    view, bowl = env.sim, "akita_black_bowl_1"
    plate, base = view.position("plate_1")[:2], view.robot_base_position()[:2]
    centre = shape_of(view, bowl).centre[:2]

    def reach_at_plate(grasp) -> float:
        return float(np.linalg.norm(plate + grasp.position[:2] - centre - base))

    assert reach_at_plate(choose_grasp(view, bowl)) > REACH_LIMIT
    assert reach_at_plate(choose_grasp(view, bowl, destination=plate)) <= REACH_LIMIT
    env.close()
    success, _, verdict = _solve("libero_spatial", 4, init=2, reset_seed=8)
    assert success and verdict["violated"] == [], verdict["events"][:3]


def test_the_wrist_stays_off_its_stop_when_the_arm_swings_to_the_grasp():
    """libero_spatial/1 (reset seed 0, init 5): reaching the bowl swings the arm ~0.4 rad about its base
    and the last joint turns back as much to hold the hand's yaw. Judged from the start pose alone, the
    grasp drove that joint into its stop (2.90 rad), OSC dragged the hand instead of turning it and the
    pick ran out of time."""
    env = make_env("libero_spatial", 1, seed=0)
    obs, _ = env.reset(seed=0, options={"init_state": 5})
    expert = ScriptedExpert(env, quality="clean", seed=0)
    expert.reset(env.metadata, episode=0)
    info, wrist = {"success": False}, 0.0
    for _ in range(env.max_steps):
        obs, _, terminated, truncated, info = env.step(expert(obs))
        wrist = max(wrist, abs(float(env.sim.arm_joints()[6])))
        if terminated or truncated:
            break
    env.close()
    assert info["success"] and wrist < 2.8, wrist


def test_a_tipped_bowl_is_pinched_where_its_wall_stands_upright():
    """A bowl resting tipped ~51 deg (libero_spatial/5's, once it slides off its ramekin, as it does under
    MuJoCo 3.4 and later). Rim grasps placed as for an upright bowl met a wall leaning across the fingers,
    which slipped out as they closed (1 in 10 solved); only the two sides level with the axis it tipped
    about offer an upright wall. On the default stack the bowl stays on its ramekin, and the task is solved."""
    env = make_env("libero_spatial", 5, seed=0)
    env.reset(options={"init_state": 0})
    view, bowl = env.sim, "akita_black_bowl_1"
    joint = env.domain.sim.model.get_joint_qpos_addr(env.domain.get_object(bowl).joints[0])[0]
    data = env.domain.sim.data._data
    tip = np.deg2rad(51.0)
    data.qpos[joint + 3 : joint + 7] = [np.cos(tip / 2), np.sin(tip / 2) * 0.6, np.sin(tip / 2) * 0.8, 0.0]
    env.domain.sim.forward()
    up = view.rotation(bowl)[:, 2]
    assert np.rad2deg(np.arccos(up[2])) == pytest.approx(51.0)
    tipping = up[:2] / np.linalg.norm(up[:2])  # the horizontal direction the bowl leans towards
    grasps = [g for yaw in YAWS for g in _rim_grasps(view, bowl, float(yaw))]
    assert grasps and all(abs(finger_axis(g.yaw)[:2] @ tipping) < np.sin(np.deg2rad(16)) for g in grasps)
    env.close()
    success, _, _ = _solve("libero_spatial", 5, init=0)
    assert success


def test_a_drawer_is_pushed_shut_with_the_fingertips_past_a_wine_rack():
    """libero_10/3: the bottom drawer starts open with a wine rack in front of the cabinet. Pushing with
    the hand horizontal, the forearm ran into the rack and the drawer stayed open; pointing down and
    pitched towards the cabinet, the fingertips push it shut."""
    env = make_env("libero_10", 3, seed=0)
    env.reset(options={"init_state": 0})
    drawer = "white_cabinet_1_bottom_region"
    assert not env.sim.predicate(("close", drawer))
    closed, touched = _run_skill(env, articulated.close(SkillContext(env.sim, np.random.default_rng(0)), drawer))
    assert closed and env.sim.predicate(("close", drawer))
    assert "wine_rack_1" not in touched
    env.close()


def test_a_partly_open_drawer_is_pulled_out_to_its_end_stop_by_hooking_its_front_panel():
    """libero_10/3 starts with the bottom drawer 1.4 cm short of its end stop, and the bowl fits between
    its front panel and the handle of the drawer above only with that 1.4 cm: the plan pulls it out
    first, the fingertips hooked behind the front panel (no turn of the hand to level and back)."""
    env = make_env("libero_10", 3, seed=0)
    env.reset(options={"init_state": 0})
    drawer = "white_cabinet_1_bottom_region"
    plan = [pred for pred, _ in plan_skills(env.task.goal, env.sim)]
    assert plan[0] == ("pull_out", drawer) and plan[-1] == ("close", drawer)
    assert articulated.pulled_short(env.sim, drawer) > articulated.FULLY_OUT
    done, touched = _run_skill(
        env, articulated.pull_out(SkillContext(env.sim, np.random.default_rng(0)), drawer), max_steps=120
    )
    assert done and articulated.pulled_short(env.sim, drawer) < articulated.FULLY_OUT / 2
    assert touched <= {"white_cabinet_1"}
    env.close()


def test_a_bowl_is_set_down_in_the_few_millimetres_a_drawer_leaves_it():
    """With libero_10/3's bottom drawer at its end stop, a 10.7 cm bowl has 11.6 cm between the drawer's
    front panel and the handle of the drawer above. The spot search must find that gap (its coarse
    lattice saw the 22 cm front panel at three points along its length and could not tell a footprint
    3 mm clear of an obstacle from one 3 mm into it) and keep to the region's centre across the drawer."""
    env = make_env("libero_10", 3, seed=0)
    env.reset(options={"init_state": 0})
    view, bowl, drawer = env.sim, "akita_black_bowl_1", "white_cabinet_1_bottom_region"
    joint = view.articulation_joints(drawer)[0]
    env.domain.sim.data.set_joint_qpos(joint, view.joint(joint)["range"][0])
    env.domain.sim.forward()
    spot = skills.target_xy(view, drawer, held=bowl)
    region = view.region(drawer)
    above = region.position[2] + 0.01
    boxes = view.geom_points("white_cabinet_1").reshape(-1, 8, 3)
    cabinet = fill_boxes(boxes[boxes[:, :, 2].max(axis=1) > above], spacing=0.002)
    cabinet = cabinet[(cabinet[:, 2] > above) & (np.linalg.norm(cabinet[:, :2] - spot, axis=1) < 0.07)][:, :2]
    footprint = view.geom_points(bowl)[:, :2] - view.position(bowl)[:2] + spot
    outline = footprint[ConvexHull(footprint).vertices]
    assert not (Delaunay(outline).find_simplex(cabinet) >= 0).any()
    start, edge = outline, np.roll(outline, -1, axis=0) - outline
    along = np.clip(((cabinet[:, None] - start) * edge).sum(-1) / (edge * edge).sum(-1), 0, 1)
    assert np.linalg.norm(cabinet[:, None] - (start + along[..., None] * edge), axis=-1).min() > 0.002
    axes, _ = region.footprint()
    assert np.all(np.abs((spot - region.centre[:2]) @ axes) < 0.025)
    env.close()


def test_spots_are_judged_by_the_footprint_an_object_will_stand_on():
    """A bowl hanging 15 deg tilted from a rim grasp lands flat, so its spot is judged by its upright
    footprint; a can lying on its side (libero_10/7's alphabet soup) stays lying."""
    env = make_env("libero_10", 7, seed=0)
    env.reset(options={"init_state": 26})
    view = env.sim
    can = "alphabet_soup_1"
    assert view.tilt(can) > 1.4
    assert np.abs(standing_points(view, can) - view.geom_points(can)).max() < 0.005
    env.close()
    env = make_env("libero_10", 3, seed=0)
    env.reset(options={"init_state": 0})
    view, bowl = env.sim, "akita_black_bowl_1"
    upright = view.geom_points(bowl)
    joint = env.domain.get_object(bowl).joints[0]
    pose = env.domain.sim.data.get_joint_qpos(joint).copy()
    pose[3:] = [np.cos(0.125), np.sin(0.125), 0.0, 0.0]  # 15 deg about x (wxyz)
    env.domain.sim.data.set_joint_qpos(joint, pose)
    env.domain.sim.forward()
    assert abs(view.tilt(bowl) - 0.25) < 0.01
    tilted, standing = view.geom_points(bowl), standing_points(view, bowl)
    height = lambda pts: float(np.ptp(pts[:, 2]))  # noqa: E731
    assert height(tilted) > height(upright) + 0.01
    assert abs(height(standing) - height(upright)) < 0.001
    env.close()


def test_an_open_microwave_is_not_opened_again_and_swings_shut():
    """libero_10/9 starts with the microwave door open. LIBERO calls its heating region never open (the
    region has no joint of its own), so the plan opened the open door; and the door swung the wrong way:
    LIBERO's microwave opens towards negative hinge angles, so "opening" it pushed it shut."""
    env = make_env("libero_10", 9, seed=0)
    env.reset(options={"init_state": 0})
    mug, region = "white_yellow_mug_1", "microwave_1_heating_region"
    assert [pred for pred, _ in plan_skills(env.task.goal, env.sim)] == [("in", mug, region), ("close", "microwave_1")]
    closed, _ = _run_skill(env, articulated.close(SkillContext(env.sim, np.random.default_rng(0)), "microwave_1"))
    assert closed and env.sim.predicate(("close", "microwave_1"))
    env.close()


@pytest.mark.parametrize("suite, task, reset_seed", [("libero_object", 3, None), ("libero_goal", 4, 1874364848)])
def test_drop_knob_releases_from_height_and_is_recorded(suite, task, reset_seed):
    """Released at carrying height, the object's bottom hung exactly the carry margin (5 cm) over the
    cabinet top of libero_goal/4 (the label benchmark's demo 40, reset seed 1874364848), the ITC's own
    drop limit, so the "drop" was not one; the knob now lets go twice that high above what lies below."""
    success, expert, verdict = _solve(suite, task, quality={"drop": 1.0}, reset_seed=reset_seed)
    assert expert.knobs["drop"] and "drop" in expert.events
    assert "collision" in verdict["violated"] and any("dropped" in e[-1] for e in verdict["events"]), verdict


def test_misplace_sets_the_object_down_beside_its_container_and_is_recorded_at_the_release():
    """The misplace event comes as the object is let go over the wrong spot, not when the offset is drawn
    at the pick-up spot: an episode that times out before the release misplaced nothing. Into a basket
    the wrong spot is beside it: released 5-8 cm off-centre, the basket's sloped wall slid the object back
    within tolerance (libero_object/5, init 5), and the knob went unseen by the labels."""
    env = ITCWrapper(make_env("libero_object", 3, seed=0))
    obs, _ = env.reset(options={"init_state": 0})
    sim = env.unwrapped.sim
    ((_, obj, region),) = env.unwrapped.task.goal
    basket = sim.region(region).parent
    expert = ScriptedExpert(env.unwrapped, quality={"misplace": 1.0}, seed=0)
    expert.reset(env.unwrapped.metadata, episode=0)
    supports_at_event = None
    for _ in range(env.unwrapped.max_steps):
        obs, _, terminated, truncated, info = env.step(expert(obs))
        if supports_at_event is None and "misplace" in expert.events:
            supports_at_event = {c.other(obj) for c in sim.contacts() if c.involves(obj)} - {"gripper", "robot"}
            basket_xy = sim.geom_points(basket)[:, :2]
            held_xy = sim.geom_points(obj)[:, :2]
        if terminated or truncated:
            break
    env.close()
    assert supports_at_event and basket not in supports_at_event  # set down on the floor, about to be let go
    # beside the basket: the object's footprint clear of the basket's along some axis
    assert (
        held_xy[:, 0].min() > basket_xy[:, 0].max()
        or held_xy[:, 0].max() < basket_xy[:, 0].min()
        or held_xy[:, 1].min() > basket_xy[:, 1].max()
        or held_xy[:, 1].max() < basket_xy[:, 1].min()
    )
    assert not info["success"] and "pose_accuracy" in info["itc_verdict"]["violated"]


def _collect(tmp_path, name, **kw):
    out = str(tmp_path / name)
    summary = collect.collect_demos(
        "libero_object", [0], out, episodes=2, quality={"tilt": 0.5}, seed=4, progress=False, **kw
    )
    return out, summary


def test_demos_file_layout_and_interrupted_resume_matches_uninterrupted(tmp_path, monkeypatch):
    full, summary = _collect(tmp_path, "full.hdf5")
    assert summary["demos"] == 2 and summary["success_rate"] == 1.0
    with h5py.File(full) as f:
        data = f["data"]
        assert data.attrs["format_version"] == "libero-elegant/1"
        assert "env_args" in data.attrs and "problem_info" in data.attrs and "language_instruction" in data.attrs
        demo = data["demo_0"]
        t = demo["actions"].shape[0]
        assert demo["states"].shape[0] == t and demo["obs/state"].shape[0] == t and demo["next_obs/state"].shape[0] == t
        assert demo["rewards"][-1] == 1.0 and demo["dones"][-1] == 1
        assert {"knobs", "expert_version", "init_state_index"} <= set(demo.attrs)
    interrupted_at_second_episode(monkeypatch, lambda: _collect(tmp_path, "resumed.hdf5"))
    assert (tmp_path / "resumed.hdf5.partial").exists() and not (tmp_path / "resumed.hdf5").exists()
    with pytest.raises(
        UserInputError, match="cannot resume with different episodes"
    ):  # demo_<i>'s task depends on the count
        collect.collect_demos(
            "libero_object",
            [0],
            str(tmp_path / "resumed.hdf5"),
            episodes=3,
            quality={"tilt": 0.5},
            seed=4,
            progress=False,
            resume=True,
        )
    resumed, _ = _collect(tmp_path, "resumed.hdf5", resume=True)
    with DemoFile(full) as a, DemoFile(resumed) as b:
        assert len(a) == len(b) == 2
        for da, db in zip(a, b):
            assert np.array_equal(da.actions, db.actions) and np.array_equal(da.obs, db.obs)
            assert da.attrs["knobs"] == db.attrs["knobs"]
