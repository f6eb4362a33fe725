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
