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
