"""`elegant robustness` on the real simulator at tiny sizes: the runs it makes, LIBERO-PRO's table recomputed
by hand from the episode records, resume, and the refusals before any work."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from annotations.collect import collect_demos
from base_suites.runtime.errors import UserInputError
from elegant.cli import main
from elegant.evaluation.config import RobustnessConfig
from elegant.evaluation.robustness import run_robustness
from elegant.policies.bc_train import train_policy

pytestmark = pytest.mark.sim
SUITE = "libero_object"
AXES = ("object", "position", "probe_empty")
EVAL = {"mode": "base", "episodes": 2, "max_steps": 8, "seed": 0, "init_states": (0, 1), "progress": False}


@pytest.fixture(scope="module")
def policy(tmp_path_factory) -> str:
    root = tmp_path_factory.mktemp("robustness")
    demos = str(root / "demos.hdf5")
    collect_demos(SUITE, [0], demos, episodes=1, quality="clean", seed=0, progress=False)
    out = str(root / "policy")
    train_policy([demos], out, epochs=1, chunk=1, progress=False)
    return out


@pytest.fixture(scope="module")
def run(policy, tmp_path_factory):
    out = tmp_path_factory.mktemp("pro") / "run"
    return out, run_robustness([SUITE], policy, None, out, RobustnessConfig(axes=AXES), tasks=[0], **EVAL)


def records(run_dir) -> list[dict]:
    return [json.loads(line) for line in (run_dir / "episodes.jsonl").read_text().splitlines()]


def test_one_run_per_axis_with_its_perturbation(run):
    out, result = run
    expected = {
        "ori": None,
        "object": "object,object@texture,object@scale",
        "position": "init",
        "probe_empty": "probe@empty",
    }
    for axis, perturbation in expected.items():
        config = json.loads((out / SUITE / axis / "config.json").read_text())
        assert config["perturbation"] == perturbation and config["episodes"] == 2 and config["seed"] == 0
    # Every axis plays the same starts as the original.
    starts = {axis: [r["init_index"] for r in records(out / SUITE / axis)] for axis in expected}
    assert len({tuple(s) for s in starts.values()}) == 1
    assert result["config"]["axes"] == {"ori": "", **{a: expected[a] for a in AXES}}


def test_table_recomputed_by_hand_from_the_episode_records(run):
    out, result = run
    for name, field in (("success", "success"), ("elegant", "elegant")):
        acc = {axis: np.mean([r[field] for r in records(out / SUITE / axis)]) for axis in ("ori", *AXES)}
        row = dict(result[name][SUITE])
        assert row["acc_ori"] == acc["ori"]
        for axis in ("object", "position"):
            assert row["acc"][axis] == acc[axis] and row["gap"][axis] == acc["ori"] - acc[axis]
        assert row["pro"] == pytest.approx((acc["object"] + acc["position"]) / 2)
        assert row["probes"] == {"probe_empty": {"acc": acc["probe_empty"], "gap": acc["ori"] - acc["probe_empty"]}}
        intervals = row.pop("ci95")  # each run's own interval over starts, as its summary gives it
        key = "success_ci95" if name == "success" else "esr_ci95"
        for axis in ("ori", *AXES):
            assert intervals[axis] == json.loads((out / SUITE / axis / "summary.json").read_text())[key]
        assert result[name]["total"] == row  # one suite: the total is its row (the total has no interval)
    assert json.loads((out / "robustness.json").read_text()) == json.loads(json.dumps(result))
    report = (out / "report.md").read_text()
    assert "## From success" in report and "## From elegant success (ESR)" in report
    assert (out / "robustness.png").stat().st_size > 0


def test_resume_reruns_nothing_and_refuses_other_settings(run, policy):
    out, result = run
    files = list(out.rglob("episodes.jsonl"))
    before = {p: p.stat().st_mtime_ns for p in files}
    again = run_robustness([SUITE], policy, None, out, RobustnessConfig(axes=AXES), tasks=[0], resume=True, **EVAL)
    assert again == result and {p: p.stat().st_mtime_ns for p in files} == before
    with pytest.raises(UserInputError, match="field 'evaluation.seed' is 0 but this run has 1"):
        run_robustness(
            [SUITE], policy, None, out, RobustnessConfig(axes=AXES), tasks=[0], resume=True, **{**EVAL, "seed": 1}
        )


def test_resume_with_more_episodes_extends_every_axis(run, policy, tmp_path):
    """More episodes per task extend each axis's run: its finished episodes are kept as they were, and the
    table counts the new ones; the run then equals a fresh one with as many episodes."""
    out, _ = run
    grown = tmp_path / "grown"
    shutil.copytree(out, grown)
    kept = {axis: records(grown / SUITE / axis) for axis in ("ori", *AXES)}
    more = {**EVAL, "episodes": 3, "init_states": (0, 1, 2)}
    with pytest.raises(UserInputError, match="field 'evaluation.init_states'"):
        run_robustness([SUITE], policy, None, grown, RobustnessConfig(axes=AXES), tasks=[0], resume=True, **more)
    more["init_states"] = EVAL["init_states"]
    with pytest.warns(UserWarning, match="3 episodes per task from 2 starts"):
        result = run_robustness(
            [SUITE], policy, None, grown, RobustnessConfig(axes=AXES), tasks=[0], resume=True, **more
        )
    assert result["config"]["evaluation"]["episodes"] == 3
    for axis, before in kept.items():
        after = records(grown / SUITE / axis)
        assert len(after) == 3 and after[:2] == before
        summary = json.loads((grown / SUITE / axis / "summary.json").read_text())
        assert summary["episodes"] == 3
    fresh = run_robustness([SUITE], policy, None, tmp_path / "fresh", RobustnessConfig(axes=AXES), tasks=[0], **more)
    assert result["success"] == fresh["success"] and result["elegant"] == fresh["elegant"]


def test_refusals_before_any_work(policy, tmp_path, capsys):
    with pytest.raises(UserInputError, match=r"the task axis of libero_object plays libero_object_task/0"):
        run_robustness(
            [SUITE], policy, None, tmp_path / "a", RobustnessConfig(axes=("object", "task")), tasks=[0], **EVAL
        )
    with pytest.raises(UserInputError, match="each axis sets its own perturbation"):
        run_robustness([SUITE], policy, None, tmp_path / "b", tasks=[0], perturbation="init", **EVAL)
    with pytest.raises(UserInputError, match="unknown robustness axis 'lighting'"):
        RobustnessConfig(axes=("object", "lighting"))
    with pytest.raises(UserInputError, match="no shipped LIBERO-PRO 'task' variant"):
        run_robustness(["libero_90"], policy, None, tmp_path / "c", RobustnessConfig(axes=("task",)), tasks=[0], **EVAL)
    args = ["robustness", "--suite", SUITE, "--tasks", "0", "--policy", policy, "--out", str(tmp_path / "d")]
    assert main([*args, "--mode", "base", "--axes", "semantic,task"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "leave the axis out (--axes semantic)" in err
    args[-1] = str(tmp_path / "e")  # JITI, the default mode, without a critic: refused by the first run
    assert main([*args, "--axes", "object", "--episodes", "1", "--max-steps", "4"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "JITI mode 'jiti' needs a critic" in err
    (tmp_path / "g" / "mine").mkdir(parents=True)  # a directory of the user's: only what the run wrote goes
    for name in "fg":  # refused by the first run itself: what the robustness run wrote goes too
        with pytest.raises(UserInputError, match=r"init states \[60\]: expected indices in 0..49"):
            bad = {**EVAL, "init_states": (60,)}
            run_robustness([SUITE], policy, None, tmp_path / name, RobustnessConfig(axes=AXES), tasks=[0], **bad)
    assert not any((tmp_path / d).exists() for d in "abcdef")
    assert sorted(p.name for p in (tmp_path / "g").iterdir()) == ["mine"]
