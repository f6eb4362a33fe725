"""Constraint specs derived from BDDL (no simulator), YAML overrides and their refusals, parameters, windows."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from base_suites import UserInputError, get_task, list_tasks
from itc import CRITERIA, ITCParams, derive_spec, describe_spec, num_windows, segment_labels, window_bounds
from itc.spec import load_scene

SPECS_DIR = os.path.join(os.path.dirname(__file__), os.pardir, "itc", "specs")


def spec_of(suite: str, index: int, overrides_dir: str | None = None):
    return derive_spec(get_task(suite, index), overrides_dir)


# ---- derivation: one task of each suite -------------------------------------------------------
def test_spatial_pick_from_a_support():
    spec = spec_of("libero_spatial", 5)  # the bowl on the ramekin onto the plate
    assert spec.manipulated == ("akita_black_bowl_1",) and spec.targets == ("plate_1",)
    assert spec.supports == ("glazed_rim_porcelain_ramekin_1",)
    assert set(spec.distractors) == {"akita_black_bowl_2", "cookies_1", "glazed_rim_porcelain_ramekin_1"}
    assert {"akita_black_bowl_1", "akita_black_bowl_2"} <= set(spec.upright) and "cookies_1" not in spec.upright
    assert "glazed_rim_porcelain_ramekin_1" in spec.robot_may_touch() and "cookies_1" not in spec.robot_may_touch()
    (placement,) = spec.placements
    assert (placement.obj, placement.target, placement.target_is_region) == ("akita_black_bowl_1", "plate_1", False)


def test_object_into_basket_region():
    spec = spec_of("libero_object", 7)  # milk into the basket
    (placement,) = spec.placements
    assert placement.target == "basket_1_contain_region" and placement.target_entity == "basket_1"
    assert placement.target_is_region and spec.targets == ("basket_1",)
    assert "milk_1" in spec.upright and "butter_1" not in spec.upright
    assert "milk_1" not in spec.distractors and "butter_1" in spec.distractors and spec.idle_fixtures == ()


def test_goal_bottle_onto_wine_rack_may_lie_down_and_unnamed_fixtures_are_idle():
    spec = spec_of("libero_goal", 9)
    assert "wine_bottle_1" not in spec.upright, "a wine rack holds bottles lying"
    assert spec_of("libero_goal", 2).upright.count("wine_bottle_1") == 1, "standing on the cabinet it stays upright"
    assert set(spec.idle_fixtures) == {"wooden_cabinet_1", "flat_stove_1"}
    assert "wooden_cabinet_1" in spec_of("libero_goal", 0).targets  # "open the middle drawer"


def test_libero_10_order_follows_physics_over_bddl():
    spec = spec_of("libero_10", 3)  # BDDL lists close before in; the bowl must go in first
    assert spec.subgoals[0][0] == "close" and spec.order == ((1, 0),)
    assert spec_of("libero_10", 0).order == (), "'both' items may go in either order"
    pots = spec_of("libero_10", 8)  # both pots (any order), then the stove
    assert pots.order == ((0, 2), (1, 2))


def test_libero_90_stack_before_moving_the_stack():
    spec = spec_of("libero_90", 63)
    assert spec.order == ((0, 1),)
    assert [p.target for p in spec.placements] == ["akita_black_bowl_2", "wooden_tray_1_contain_region"]
    assert spec_of("libero_90", 26).upright.count("wine_bottle_1") == 0, "a bottle lies in a drawer"


def test_every_task_of_the_main_suites_derives_a_consistent_spec():
    for suite in ("libero_spatial", "libero_object", "libero_goal", "libero_10", "libero_90"):
        for task in list_tasks(suite):
            spec = derive_spec(task)
            scene = load_scene(task.bddl_file)
            named = (
                spec.manipulated + spec.targets + spec.supports + spec.distractors + spec.idle_fixtures + spec.upright
            )
            assert set(named) <= set(scene.entities), task.name
            assert not set(spec.manipulated) & set(spec.distractors), task.name
            pairs = set(spec.order)
            assert all(0 <= i < len(spec.subgoals) and 0 <= j < len(spec.subgoals) and i != j for i, j in pairs)
            assert not any((j, i) in pairs for i, j in pairs), f"{task.name}: contradictory order"
            assert len(spec.placements) == sum(p[0] in ("on", "in") for p in spec.subgoals), task.name
            json.dumps(spec.to_dict())


def test_describe_spec_is_printable():
    desc = describe_spec("libero_10", "3")
    assert desc["task"] == "libero_10/3"
    assert desc["order_readable"] == [
        "in(akita_black_bowl_1, white_cabinet_1_bottom_region) before close(white_cabinet_1_bottom_region)"
    ]
    assert json.loads(json.dumps(desc)) == desc


# ---- overrides ---------------------------------------------------------------------------------
def write_override(root, suite: str, index: int, text: str) -> str:
    path = root / suite / f"{index}.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return str(root)


def test_override_replaces_fields_and_per_task_params(tmp_path):
    root = write_override(
        tmp_path, "libero_10", 4, "order: []\nupright: [porcelain_mug_1]\nparams: {drop_height: 0.08}\n"
    )
    base = spec_of("libero_10", 4)
    spec = spec_of("libero_10", 4, root)
    assert base.order == ((0, 1),) and spec.order == ()
    assert spec.upright == ("porcelain_mug_1",) and spec.distractors == base.distractors
    assert spec.effective_params(ITCParams(contact_force=7.0)) == ITCParams(contact_force=7.0, drop_height=0.08)
    assert spec.overrides == (os.path.join(root, "libero_10", "4.yaml"),)
    assert spec_of("libero_10", 5, root) == spec_of("libero_10", 5), "tasks without a file keep the derived spec"


@pytest.mark.parametrize(
    "text, message",
    [
        ("colour: red\n", "unknown field 'colour'"),
        ("distractors: [teapot_1]\n", "field 'distractors': unknown entity 'teapot_1'"),
        ("upright: porcelain_mug_1\n", "field 'upright' must be a list of entity names"),
        ("order: [[0, 5]]\n", "field 'order' must be a list of [i, j] pairs of sub-goal indices 0..1"),
        ("order: [[1, 1]]\n", "with i != j"),
        ("params: {drop_hight: 0.1}\n", "unknown ITC parameter 'drop_hight'"),
        ("params: {drop_height: high}\n", "ITC parameter 'drop_height' must be a number"),
        ("params: {segment_length: 10}\n", "segment_length is one value per annotated file"),
        ("- order\n", "expected a mapping of spec fields"),
        ("order: [[0, 1]\n", "not valid YAML"),
    ],
)
def test_bad_override_files_are_refused_with_file_and_field(tmp_path, text, message):
    root = write_override(tmp_path, "libero_10", 4, text)
    with pytest.raises(
        UserInputError, match=message.replace("[", r"\[").replace("]", r"\]").replace("(", r"\(")
    ) as err:
        spec_of("libero_10", 4, root)
    assert str(err.value).startswith(os.path.join(root, "libero_10", "4.yaml"))


def test_missing_overrides_directory_is_refused(tmp_path):
    with pytest.raises(UserInputError, match="overrides directory does not exist"):
        spec_of("libero_10", 4, str(tmp_path / "nope"))


def test_shipped_example_override_is_valid():
    spec = spec_of("libero_10", 4, SPECS_DIR)
    assert spec.order == () and spec.overrides


# ---- parameters and windows --------------------------------------------------------------------
def test_params_round_trip_and_refusals():
    params = ITCParams.from_dict({"drop_height": 0.1, "rest_steps": 4})
    assert ITCParams.from_dict(params.to_dict()) == params and params.rest_steps == 4
    assert abs(ITCParams().upright_tolerance - np.radians(20)) < 1e-12
    with pytest.raises(UserInputError, match="must be an integer"):
        ITCParams.from_dict({"rest_steps": 2.5})
    with pytest.raises(UserInputError, match="must be >= 0"):
        ITCParams.from_dict({"drop_height": -1})
    with pytest.raises(UserInputError, match="must be >= 1"):
        ITCParams.from_dict({"segment_length": 0})


def test_windows_and_segment_labels():
    assert num_windows(0, 25) == 0 and num_windows(25, 25) == 1 and num_windows(26, 25) == 2
    assert window_bounds(60, 25) == [(0, 24), (25, 49), (50, 59)]
    kept = np.ones(60, dtype=bool)
    kept[49] = False
    assert segment_labels(kept, 25).tolist() == [True, False, True]
    assert segment_labels(np.ones(0, dtype=bool), 25).shape == (0,)
    assert CRITERIA == ("sequence", "pose_accuracy", "alignment", "collision")
