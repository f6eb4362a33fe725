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


class LeRobotStyle:
    """A LeRobot-style policy: `select_action(batch)` on a batch of one, `reset()`; remembers what it saw."""

    def __init__(self):
        self.batches = []

    def select_action(self, batch):
        import torch

        self.batches.append({k: (v.shape if hasattr(v, "shape") else v) for k, v in batch.items()})
        return torch.tensor([[0.0, 0.0, -0.5, 0.0, 0.0, 0.0, -1.0]])

    def reset(self):
        pass


LAST_LEROBOT = []


def make_lerobot_style():
    policy = LeRobotStyle()
    LAST_LEROBOT.append(policy)
    return policy
