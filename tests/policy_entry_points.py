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


class ReachCritic:
    """A critic object (picklable: it reaches Ray actors by value) scoring the hand's height and how close
    an action's motion is to a downward push."""

    def bind(self, metadata):
        return self

    def q(self, state, actions):
        return 5.0 * state[2] - np.linalg.norm(np.asarray(actions)[:, :3] - [0.05, 0.0, -1.0], axis=1)


def make_self_killing(marker: str, after: int = 5):
    """`make_policy()`, except that the first process to make its `after`-th call kills itself by its own
    pid (SIGKILL, as the OOM killer would), leaving `marker` behind so that no other process does."""
    import os
    import signal

    act, calls = make_policy(), [0]

    def killing(obs):
        calls[0] += 1
        if calls[0] == after and not os.path.exists(marker):
            open(marker, "w").close()
            os.kill(os.getpid(), signal.SIGKILL)
        return act(obs)

    return killing
