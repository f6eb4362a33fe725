"""benchmarks/unseen_tasks.py end to end at tiny sizes on the real simulator: goal-relative critics trained
on one task judge another, paired with base on the same starts, beside the task one-hot on every task."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

BENCHMARK = os.path.join(os.path.dirname(__file__), os.pardir, "benchmarks", "unseen_tasks.py")
TINY = (
    "--suites libero_object --tasks 0,1 --seen 0 --unseen 1 --demos 2 --no-successful-only --policy-epochs 1 "
    "--critic-rollouts 2 --rollout-explore-at 8 --critic-steps 5 --critic-hidden 16,16 --critic-members 2 "
    "--episodes 2 --max-steps 24 --no-jiti-gate"
).split()


def test_overlapping_task_groups_are_refused_before_anything_runs(tmp_path):
    done = subprocess.run(
        [sys.executable, BENCHMARK, "--out", str(tmp_path / "run"), "--seen", "0-4", "--unseen", "4-9"],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2 and "--seen and --unseen share tasks [4]" in done.stderr
    assert not (tmp_path / "run").exists()


@pytest.mark.sim
def test_critics_trained_on_seen_tasks_judge_unseen_ones_paired_with_base(tmp_path):
    out = tmp_path / "chain"
    done = subprocess.run(
        [sys.executable, BENCHMARK, "--out", str(out), *TINY, "--gate", "--compare-encodings", "--workers", "1"],
        capture_output=True,
        text=True,
        cwd=os.path.join(os.path.dirname(__file__), os.pardir),
    )
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    row = result["per_suite"]["libero_object"]
    folder = out / "unseen" / "libero_object"
    for k in (1, 2):
        training = json.load(open(folder / "seen_critics" / f"critic_{k}" / "critic.json"))
        assert training["encoder"] == {"kind": "goal-relative", "version": 1, "tasks": ["libero_object/0"]}
    gated_config = json.load(open(folder / "jiti_unseen_gated" / "config.json"))
    unseen_base = row["unseen"]["modes"]["base"]
    for group, task in (("unseen", 1), ("seen", 0)):
        modes = row[group]["modes"]
        assert set(modes) == {"base", "jiti"} and modes["base"]["starts"] == modes["jiti"]["starts"] == 2
        assert modes["jiti"]["made_elegant"] + modes["jiti"]["spoiled"] <= 2
        assert row[group]["auroc"] is None or 0.0 <= row[group]["auroc"] <= 1.0  # None: one kind of step only
        summary = json.load(open(folder / f"jiti_{group}" / "summary.json"))
        assert list(summary["per_task"]) == [f"libero_object/{task}"]
    assert set(row["encodings"]) == {"task-onehot", "goal-relative"}
    # The gate for the unseen task comes from its own validation runs on the rollout starts (0-24), with the
    # critics that never learned from it; its JITI run plays the held-out starts that base played.
    gate = json.load(open(folder / "gate_unseen.json"))
    assert set(gate["tasks"]) == {"libero_object/1"}
    for mode in ("base", "jiti"):
        validation = json.load(open(folder / f"validate_{mode}_unseen" / "config.json"))
        assert max(validation["init_states"]) < 25 and validation["critic"] == gated_config["critic"]
    gated = row["unseen_gated"]["modes"]
    assert gated["base"] == unseen_base and gated["jiti"]["starts"] == 2
    assert min(gated_config["init_states"]) >= 25
    verdicts = result["verdicts"]["libero_object"]
    unseen = row["unseen"]["modes"]
    assert verdicts["unseen_esr_gain"] == pytest.approx(unseen["jiti"]["esr"] - unseen["base"]["esr"])
