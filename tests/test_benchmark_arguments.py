"""The effect benchmark refuses a bad setting when it parses its arguments, not hours into the chain."""

import os
import subprocess
import sys

BENCHMARK = os.path.join(os.path.dirname(__file__), os.pardir, "benchmarks", "jiti_effect.py")


def test_jiti_effect_refuses_an_unknown_critic_reward_before_running_anything(tmp_path):
    out = tmp_path / "run"
    done = subprocess.run(
        [sys.executable, BENCHMARK, "--out", str(out), "--critic-reward", "bogus"], capture_output=True, text=True
    )
    assert done.returncode == 2
    assert "--critic-reward: invalid choice: 'bogus'" in done.stderr
    assert "'elegant'" in done.stderr  # every reward the critic trains on is offered
    assert not out.exists()


def test_packnet_capacity_refuses_a_bad_fraction_or_a_run_that_is_not_packnet(tmp_path):
    script = os.path.join(os.path.dirname(BENCHMARK), "packnet_capacity.py")
    out = tmp_path / "probes"
    run = tmp_path / "seed_0"
    run.mkdir()
    (run / "config.json").write_text('{"algorithm": "er", "task_keys": ["libero_object/0"]}')
    for extra, expected in (
        (["--fractions", "0.5,2"], "--fractions: expected comma-separated numbers in (0, 1], got '0.5,2'"),
        ([], "config.json: algorithm is 'er', not packnet"),
    ):
        done = subprocess.run(
            [sys.executable, script, str(run), "--out", str(out), *extra], capture_output=True, text=True
        )
        assert done.returncode == 1
        assert expected in done.stderr and "Traceback" not in done.stderr
        assert not out.exists()


def test_settle_drift_counts_the_starts_that_moved_and_marks_the_unstable_ones(tmp_path):
    """`compare` on two hand-written records: a start whose bowl ends 2 cm away, one whose book ends tipped
    0.3 rad under a release MuJoCo called unstable, one within tolerance; the table counts 2 moved, 1 of
    them with both releases stable, and names both."""
    import json

    stack = {"mujoco": "2.3.7"}
    reference = {
        "stack": stack,
        "starts": {
            "libero_10/0/0": {"bowl": [0.0, 0.0, 0.9, 0.0]},
            "libero_10/0/1": {"book": [0.1, 0.0, 0.9, 0.0]},
            "libero_10/0/2": {"bowl": [0.0, 0.1, 0.9, 0.0]},
        },
        "unstable": ["libero_10/0/1"],
    }
    other = {
        "stack": {"mujoco": "3.3.7"},
        "starts": {
            "libero_10/0/0": {"bowl": [0.02, 0.0, 0.9, 0.0]},
            "libero_10/0/1": {"book": [0.1, 0.0, 0.9, 0.3]},
            "libero_10/0/2": {"bowl": [0.005, 0.1, 0.9, 0.05]},
        },
        "unstable": [],
    }
    paths = []
    for name, record in (("ref", reference), ("other", other)):
        paths.append(tmp_path / f"{name}.json")
        paths[-1].write_text(json.dumps(record))
    script = os.path.join(os.path.dirname(BENCHMARK), "settle_drift.py")
    done = subprocess.run([sys.executable, script, "compare", *map(str, paths)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.splitlines()[-1]) == {
        "3.3.7": {"starts": 3, "moved": 2, "moved_stable": 1, "unstable": {"reference": 1, "other": 0}}
    }
    assert "| libero_10 | 3 | 2 | 1 | 2.00 | 0.300 |" in done.stdout
    assert "- libero_10/0/0 bowl 2.0 cm 0.000 rad\n" in done.stdout
    assert "- libero_10/0/1 book 0.0 cm 0.300 rad (unstable under reference)" in done.stdout
