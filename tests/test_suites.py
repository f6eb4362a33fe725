"""The suite catalogue: every shipped suite lists its tasks with goals and init states."""

import pytest

from base_suites import UserInputError, get_task, list_suites, list_tasks, task_specs


def test_every_suite_lists_tasks_with_goals_and_init_states():
    for suite in list_suites():
        tasks = list_tasks(suite)
        assert len(tasks) == (90 if suite == "libero_90" else 10), suite
        for t in tasks:
            assert t.goal and all(isinstance(p, tuple) and len(p) >= 2 for p in t.goal)
            assert t.language
            assert t.n_init_states == 50


def test_pro_variants_change_what_they_claim():
    base = get_task("libero_goal", 0)
    assert get_task("libero_goal_lan", 0).language != base.language
    assert get_task("libero_goal_lan", 0).goal == base.goal
    assert get_task("libero_goal_task", 0).goal != base.goal
    assert get_task("libero_object_object", 0).goal != get_task("libero_object", 0).goal


def test_unknown_suite_and_task_are_refused_with_choices():
    with pytest.raises(UserInputError, match="expected one of: .*libero_spatial"):
        list_tasks("libero_nope")
    with pytest.raises(UserInputError, match="0..9"):
        get_task("libero_goal", 10)
    assert get_task("libero_goal", "open_the_middle_drawer_of_the_cabinet").index == 0


def test_task_specs_takes_every_task_of_the_suite_by_default_and_the_chosen_ones_in_order():
    """Demo and rollout collection default to task_specs(suite, None): libero_90 must give all 90, not ten."""
    assert [s.index for s in task_specs("libero_90")] == list(range(90))
    assert [s.index for s in task_specs("libero_goal", [3, "open_the_middle_drawer_of_the_cabinet"])] == [3, 0]
