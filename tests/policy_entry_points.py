"""Entry points for the `module:factory` policy spec tests (importable because tests/ is on sys.path)."""

import numpy as np


def make_policy(gain: float = 1.0):
    """A callable policy pushing the hand down at `gain`, with the gripper open."""

    def act(obs):
        return np.array([0.0, 0.0, -gain, 0.0, 0.0, 0.0, -1.0])

    return act


def make_nothing():
    return 42


def make_broken(**kwargs):
    raise TypeError("make_broken takes no settings")
