"""The per-task JITI gate on hand-written validation runs: its counts, its rule and its refusals."""

import json

import pytest

from base_suites import UserInputError
from elegant.intervention.gate import read_gate, task_gate, write_gate

AGENT = {
    "policy": "/runs/policy",
    "policy_act": "mode",
    "critic": "/runs/critic",
    "jiti": {"window": 4, "warmup": "steer"},
}


def write_run(path, mode, elegant_by_task, init_states=(0, 1, 2), seed=0, interventions=0, **agent):
    """A finished run: config.json (with AGENT's policy, critic and JITI settings, or `agent`'s) and one
    episodes.jsonl line per (task, episode) with its elegance (and `interventions` per episode, or {task:
    interventions})."""
    path.mkdir()
    config = {
        "format": "libero-elegant-run/2",
        "suite": "libero_goal",
        "mode": mode,
        "seed": seed,
        "init_states": list(init_states),
        "perturbation": None,
        "max_steps": None,
        **AGENT,
        **agent,
    }
    (path / "config.json").write_text(json.dumps(config))
    per_task = interventions if isinstance(interventions, dict) else dict.fromkeys(elegant_by_task, interventions)
    lines = [
        json.dumps({"task": task, "episode": i, "elegant": e, "success": e, "interventions": per_task[task]})
        for task, flags in elegant_by_task.items()
        for i, e in enumerate(flags)
    ]
    (path / "episodes.jsonl").write_text("".join(line + "\n" for line in lines))
    return path


def test_a_task_runs_jiti_only_where_jiti_turned_more_episodes_elegant_than_it_spoiled(tmp_path):
    base = write_run(
        tmp_path / "base",
        "base",
        {"libero_goal/0": [1, 1, 0, 0], "libero_goal/4": [0, 0, 0, 1], "libero_goal/1": [1, 0]},
    )
    jiti = write_run(
        tmp_path / "jiti",
        "jiti",
        {"libero_goal/0": [0, 1, 0, 0], "libero_goal/4": [1, 1, 0, 1], "libero_goal/1": [0, 1, 1]},
        interventions=3,
    )
    gate = write_gate(base, jiti, tmp_path / "gate.json")
    assert json.loads((tmp_path / "gate.json").read_text()) == gate
    assert "budget" not in gate and "always_run" not in gate
    assert gate["tasks"] == {
        "libero_goal/0": {"episodes": 4, "jiti": {"gained": 0, "lost": 1, "interventions": 3.0}, "mode": "base"},
        # a tie keeps the base policy; episode 2 is unpaired
        "libero_goal/1": {"episodes": 2, "jiti": {"gained": 1, "lost": 1, "interventions": 3.0}, "mode": "base"},
        "libero_goal/4": {"episodes": 4, "jiti": {"gained": 2, "lost": 0, "interventions": 3.0}, "mode": "jiti"},
    }
    assert read_gate(tmp_path / "gate.json", "libero_goal", ["libero_goal/4", "libero_goal/0"], [25, 26], AGENT) == {
        "libero_goal/4": "jiti",
        "libero_goal/0": "base",
    }


def test_always_is_chosen_where_it_does_best_until_the_suite_spends_its_intervention_budget(tmp_path):
    tasks = [f"libero_goal/{i}" for i in range(4)]
    base = write_run(tmp_path / "base", "base", dict.fromkeys(tasks, [0, 0, 0, 0]))
    # jiti: +1 on tasks 0-2, nothing on 3; always: +3 on 0, +2 on 1, +1 on 2 (a tie with jiti), +2 on 3
    jiti = write_run(
        tmp_path / "jiti",
        "jiti",
        {tasks[0]: [1, 0, 0, 0], tasks[1]: [1, 0, 0, 0], tasks[2]: [1, 0, 0, 0], tasks[3]: [0, 0, 0, 0]},
        interventions=2,
    )
    always = write_run(
        tmp_path / "always",
        "always",
        {tasks[0]: [1, 1, 1, 0], tasks[1]: [1, 1, 0, 0], tasks[2]: [1, 0, 0, 0], tasks[3]: [1, 1, 0, 0]},
        interventions=20,
    )
    modes = lambda gate: {t: row["mode"] for t, row in gate["tasks"].items()}  # noqa: E731
    # without a binding budget always wins wherever it made more elegant; the tie on task 2 keeps jiti
    roomy = task_gate(base, jiti, always, budget=1.0)
    assert modes(roomy) == {tasks[0]: "always", tasks[1]: "always", tasks[2]: "jiti", tasks[3]: "always"}
    # 40% of always's 20 per episode is 8: (20 + 2 + 2 + 0) / 4 = 6 fits one always task, the one that gains
    # most over its fallback per saved intervention (task 0: 2 over jiti per 18 saved, task 1: 1 per 18,
    # task 3: 2 over base per 20)
    tight = task_gate(base, jiti, always)
    assert tight["interventions_limit"] == pytest.approx(8.0) and tight["budget"] == 0.4
    assert modes(tight) == {tasks[0]: "always", tasks[1]: "jiti", tasks[2]: "jiti", tasks[3]: "base"}
    assert sum({"base": 0, "jiti": 2, "always": 20}[m] for m in modes(tight).values()) / 4 <= 8
    with pytest.raises(UserInputError, match="budget must be in \\(0, 1\\]"):
        task_gate(base, jiti, always, budget=0)


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
    with pytest.raises(UserInputError, match="gate.json: exists; pass --overwrite to replace it"):
        write_gate(base, jiti, tmp_path / "gate.json")  # a gate that runs used is not replaced by accident
    with pytest.raises(UserInputError, match="field 'init_states' overlaps the evaluation's starts \\(\\[2\\]\\)"):
        read_gate(tmp_path / "gate.json", "libero_goal", ["libero_goal/0"], [2, 30], AGENT)
    with pytest.raises(UserInputError, match="overlaps the evaluation's starts \\(all init states\\)"):
        read_gate(tmp_path / "gate.json", "libero_goal", ["libero_goal/0"], None, AGENT)
    with pytest.raises(UserInputError, match="field 'tasks' lacks libero_goal/3"):
        read_gate(tmp_path / "gate.json", "libero_goal", ["libero_goal/0", "libero_goal/3"], [30], AGENT)
    with pytest.raises(UserInputError, match="field 'suite' is 'libero_goal' but the evaluation is on 'libero_object'"):
        read_gate(tmp_path / "gate.json", "libero_object", ["libero_object/0"], [30], AGENT)
    with pytest.raises(UserInputError, match="missing.json: no such gate file"):
        read_gate(tmp_path / "missing.json", "libero_goal", ["libero_goal/0"], [30], AGENT)
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(UserInputError, match="bad.json: field 'format'"):
        read_gate(tmp_path / "bad.json", "libero_goal", ["libero_goal/0"], [30], AGENT)
    gate = json.loads((tmp_path / "gate.json").read_text())
    gate["tasks"]["libero_goal/0"]["mode"] = "sometimes"
    (tmp_path / "odd.json").write_text(json.dumps(gate))
    with pytest.raises(UserInputError, match="odd.json: field 'tasks.libero_goal/0.mode' is 'sometimes'"):
        read_gate(tmp_path / "odd.json", "libero_goal", ["libero_goal/0"], [30], AGENT)
    with pytest.raises(UserInputError, match="field 'mode' is 'base'; the gate needs a 'always' run"):
        task_gate(base, jiti, always_run=base)


def test_a_gate_holds_only_for_the_policy_critic_and_jiti_settings_it_validated(tmp_path):
    """The gate's choices are evidence about one JITI: validation runs with different policies or settings
    are refused, the gate records what it validated, and an evaluation with anything else is refused."""
    base = write_run(tmp_path / "base", "base", {"libero_goal/0": [0, 0]})
    jiti = write_run(tmp_path / "jiti", "jiti", {"libero_goal/0": [1, 0]})
    with pytest.raises(UserInputError, match="field 'policy' is '/runs/other' but the base run .* has '/runs/policy'"):
        task_gate(base, write_run(tmp_path / "other_policy", "jiti", {"libero_goal/0": [1, 0]}, policy="/runs/other"))
    wider = write_run(
        tmp_path / "always", "always", {"libero_goal/0": [1, 1]}, jiti={**AGENT["jiti"], "trust_radius": 0.5}
    )
    with pytest.raises(UserInputError, match="always: field 'jiti.trust_radius' is 0.5 but the JITI run .*'s is None"):
        task_gate(base, jiti, wider)
    # the warm-up shapes mode jiti only: an always run may have recorded another (runs once recorded every setting)
    steered_differently = write_run(
        tmp_path / "always2", "always", {"libero_goal/0": [1, 1]}, jiti={"window": 4, "warmup": "base"}
    )
    assert task_gate(base, jiti, steered_differently)["tasks"]["libero_goal/0"]["mode"] == "always"
    gate = write_gate(base, jiti, tmp_path / "gate.json")
    assert gate["agent"] == {**AGENT, "policy_act": "mode"}  # runs from before the field acted by the mode
    assert read_gate(tmp_path / "gate.json", "libero_goal", ["libero_goal/0"], [30], AGENT) == {"libero_goal/0": "jiti"}
    for field, value, shown in (
        ("critic", "/runs/critic_2", "'agent.critic' is '/runs/critic'"),
        ("policy_act", "sample", "'agent.policy_act' is 'mode'"),
        ("jiti", {"window": 8, "warmup": "steer"}, "'agent.jiti.window' is 4"),
    ):
        with pytest.raises(UserInputError, match=f"gate.json: field {shown} but this evaluation's is"):
            read_gate(tmp_path / "gate.json", "libero_goal", ["libero_goal/0"], [30], {**AGENT, field: value})


def test_the_gate_command_writes_the_budgeted_gate_and_refuses_a_bad_budget_in_one_line(tmp_path, capsys):
    from elegant.cli import main

    base = write_run(tmp_path / "base", "base", {"libero_goal/0": [0, 0], "libero_goal/1": [0, 0]})
    jiti = write_run(tmp_path / "jiti", "jiti", {"libero_goal/0": [1, 0], "libero_goal/1": [0, 0]}, interventions=2)
    always = write_run(
        tmp_path / "always", "always", {"libero_goal/0": [1, 1], "libero_goal/1": [1, 0]}, interventions=10
    )
    out = tmp_path / "gate.json"
    assert main(["gate", str(base), str(jiti), "--always", str(always), "--budget", "0.6", "--out", str(out)]) == 0
    gate = json.loads(out.read_text())
    assert gate["budget"] == 0.6 and {t: r["mode"] for t, r in gate["tasks"].items()} == {
        "libero_goal/0": "always",
        "libero_goal/1": "base",
    }
    capsys.readouterr()
    assert (
        main(
            ["gate", str(base), str(jiti), "--always", str(always), "--budget", "2", "--out", str(tmp_path / "no.json")]
        )
        == 2
    )
    assert capsys.readouterr().err.strip().splitlines() == [
        "elegant gate: error: gate budget must be in (0, 1] (a share of always's interventions), got 2.0"
    ]
    assert not (tmp_path / "no.json").exists()


def test_runs_measured_on_two_stacks_are_refused_naming_both(tmp_path):
    from base_suites import stack_record

    here = stack_record(render=None)
    base = write_run(tmp_path / "base", "base", {"libero_goal/0": [1]}, stack=here)
    jiti = write_run(tmp_path / "jiti", "jiti", {"libero_goal/0": [0]}, stack={**here, "mujoco": "3.14.0"})
    with pytest.raises(
        UserInputError, match=r"base was measured with mujoco '.*' but .*jiti with '3.14.0'; a gate takes"
    ):
        write_gate(base, jiti, tmp_path / "gate.json")
    assert not (tmp_path / "gate.json").exists()
