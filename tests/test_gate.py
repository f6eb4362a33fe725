"""The per-task JITI gate on hand-written validation runs: its counts, its rule and its refusals."""
import json

import pytest

from base_suites import UserInputError
from elegant.gate import read_gate, task_gate, write_gate


def write_run(path, mode, elegant_by_task, init_states=(0, 1, 2), seed=0):
    """A finished run: config.json and one episodes.jsonl line per (task, episode) with its elegance."""
    path.mkdir()
    config = {"suite": "libero_goal", "mode": mode, "seed": seed, "init_states": list(init_states), "perturbation": None, "max_steps": None}
    (path / "config.json").write_text(json.dumps(config))
    lines = [json.dumps({"task": task, "episode": i, "elegant": e, "success": e}) for task, flags in elegant_by_task.items() for i, e in enumerate(flags)]
    (path / "episodes.jsonl").write_text("".join(line + "\n" for line in lines))
    return path


def test_a_task_is_enabled_only_where_jiti_turned_more_episodes_elegant_than_it_spoiled(tmp_path):
    base = write_run(tmp_path / "base", "base", {"libero_goal/0": [1, 1, 0, 0], "libero_goal/4": [0, 0, 0, 1], "libero_goal/1": [1, 0]})
    jiti = write_run(tmp_path / "jiti", "jiti", {"libero_goal/0": [0, 1, 0, 0], "libero_goal/4": [1, 1, 0, 1], "libero_goal/1": [0, 1, 1]})
    gate = write_gate(base, jiti, tmp_path / "gate.json")
    assert json.loads((tmp_path / "gate.json").read_text()) == gate
    assert gate["tasks"] == {
        "libero_goal/0": {"episodes": 4, "gained": 0, "lost": 1, "enabled": False},
        "libero_goal/1": {"episodes": 2, "gained": 1, "lost": 1, "enabled": False},  # a tie keeps the base policy; episode 2 is unpaired
        "libero_goal/4": {"episodes": 4, "gained": 2, "lost": 0, "enabled": True},
    }
    assert read_gate(tmp_path / "gate.json", "libero_goal", ["libero_goal/4", "libero_goal/0"], [25, 26]) == {
        "libero_goal/4": True, "libero_goal/0": False}


def test_refusals_name_the_file_and_the_field(tmp_path):
    base = write_run(tmp_path / "base", "base", {"libero_goal/0": [1]})
    jiti = write_run(tmp_path / "jiti", "jiti", {"libero_goal/0": [0]})
    with pytest.raises(UserInputError, match="field 'mode' is 'jiti'; the gate needs a 'base' run"):
        task_gate(jiti, jiti)
    with pytest.raises(UserInputError, match="field 'init_states'"):
        task_gate(base, write_run(tmp_path / "other", "jiti", {"libero_goal/0": [0]}, init_states=(3, 4)))
    with pytest.raises(UserInputError, match="share no finished episode"):
        task_gate(base, write_run(tmp_path / "elsewhere", "jiti", {"libero_goal/2": [0]}))
    write_gate(base, jiti, tmp_path / "gate.json")
    with pytest.raises(UserInputError, match="field 'init_states' overlaps the evaluation's starts \\(\\[2\\]\\)"):
        read_gate(tmp_path / "gate.json", "libero_goal", ["libero_goal/0"], [2, 30])
    with pytest.raises(UserInputError, match="overlaps the evaluation's starts \\(all init states\\)"):
        read_gate(tmp_path / "gate.json", "libero_goal", ["libero_goal/0"], None)
    with pytest.raises(UserInputError, match="field 'tasks' lacks libero_goal/3"):
        read_gate(tmp_path / "gate.json", "libero_goal", ["libero_goal/0", "libero_goal/3"], [30])
    with pytest.raises(UserInputError, match="field 'suite' is 'libero_goal' but the evaluation is on 'libero_object'"):
        read_gate(tmp_path / "gate.json", "libero_object", ["libero_object/0"], [30])
    with pytest.raises(UserInputError, match="missing.json: no such gate file"):
        read_gate(tmp_path / "missing.json", "libero_goal", ["libero_goal/0"], [30])
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(UserInputError, match="bad.json: field 'format'"):
        read_gate(tmp_path / "bad.json", "libero_goal", ["libero_goal/0"], [30])
