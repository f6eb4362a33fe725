"""Moving a task's BDDL into another of LIBERO's built-in scenes (LIBERO-PRO's environment axis)."""

import os
import re

import pytest

from base_suites import UserInputError, get_task
from base_suites.scenes import SCENES, move_to_scene, scene_bddl_file, scene_of


def _text(suite: str, index: int) -> str:
    with open(get_task(suite, index).bddl_file, encoding="utf-8") as f:
        return f.read()


def test_move_rewrites_the_problem_the_workspace_and_its_regions_only():
    text = _text("libero_goal", 8)
    assert scene_of(text) == "main_table"
    moved = move_to_scene(text, "kitchen_table")
    assert scene_of(moved) == "kitchen_table" and "LIBERO_Kitchen_Tabletop_Manipulation" in moved
    assert "main_table" not in moved and re.search(r"(?m)^\s*kitchen_table - kitchen_table\s*$", moved)
    assert moved.count("(:target kitchen_table)") == text.count("(:target main_table)") > 0
    assert re.search(r"\(:language[^)]*\)", moved).group(0) == re.search(r"\(:language[^)]*\)", text).group(0)
    assert re.search(r"\(:goal.*", moved, re.S).group(0) == re.search(r"\(:goal.*", text, re.S).group(0)
    assert move_to_scene(text, "main_table") == text
    back = move_to_scene(moved, "main_table")
    assert back.split() == text.split()  # a round trip gives the task back, up to spacing


def test_floor_scene_regions_are_renamed_where_objects_start():
    text = _text("libero_object", 0)
    assert scene_of(text) == "floor"
    moved = move_to_scene(text, "study_table")
    assert "(On alphabet_soup_1 study_table_target_object_region)" in moved and "floor" not in moved


def test_refusals_and_the_shared_cache_file(tmp_path):
    with pytest.raises(UserInputError, match="expected one of"):
        move_to_scene(_text("libero_goal", 0), "garage")
    with pytest.raises(UserInputError, match="not one of LIBERO's replaceable scenes"):
        scene_of("(define (problem LIBERO_Coffee_Table_Manipulation)")
    source = get_task("libero_goal", 0).bddl_file
    path = scene_bddl_file(source, "floor")
    assert path == scene_bddl_file(source, "floor") and os.path.isfile(path)  # named by its content, written once
    with open(path, encoding="utf-8") as f:
        assert scene_of(f.read()) == "floor"
    assert set(SCENES) == {"main_table", "kitchen_table", "living_room_table", "study_table", "floor"}
