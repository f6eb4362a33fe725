"""rank-check: a critic's advantage of a rollout's explored alternative over the policy's plan, against the outcome."""

import h5py
import numpy as np
import pytest
from test_critic_data import write_annotated

from base_suites.runtime.errors import UserInputError
from elegant.diagnostics.branch_ranking import branch_ranking

EXPLORED_AT = 10
ELEGANT = {0, 1, 2, 3}


class StatePolicy:
    """A deterministic per-step policy: its action is a fixed function of the state."""

    def reset(self, metadata=None, *, seed=None):
        self.metadata = metadata

    def __call__(self, obs):
        return 0.4 * np.tanh(np.asarray(obs["state"], dtype=np.float64)[:7])

    def sample(self, obs, n):
        return np.repeat(self(obs)[None], n, axis=0)


class FirstDimCritic:
    """Q = sign * the action's first dimension, so the explored actions below rank as constructed."""

    def __init__(self, sign=1.0, chunk=1):
        self.sign, self.chunk = sign, chunk

    def bind(self, metadata):
        assert metadata["state_layout"] and metadata["suite"] == "libero_object"

    def q(self, state, actions):
        return self.sign * np.asarray(actions)[:, 0]


def branch_file(tmp_path):
    """Demos 0-6 explore step 10 (demo 5 also step 3); demo 7 explores nothing. Every other action is the
    policy's; the explored action's first dimension is +0.9 in the elegant demos 0-3 and -0.9 in 4 and 6."""
    explored = {i: [EXPLORED_AT] for i in range(7)}
    explored[5] = [3, EXPLORED_AT]
    path = write_annotated(tmp_path / "branches.hdf5", n_demos=8, lengths=(30, 31), explored_at=explored)
    policy = StatePolicy()
    with h5py.File(path, "r+") as f:
        for i in range(8):
            demo = f[f"data/demo_{i}"]
            actions = np.array([policy({"state": s}) for s in demo["obs/state"][()]])
            actions[EXPLORED_AT, 0] = 0.9 if i in ELEGANT else -0.9
            demo["actions"][...] = actions
            demo.attrs["elegant"] = i in ELEGANT
    return path


def test_the_advantage_ranks_the_explored_alternatives_by_their_outcome(tmp_path):
    path = branch_file(tmp_path)
    result = branch_ranking(path, StatePolicy(), FirstDimCritic())
    assert result["all"] == {
        "episodes": 6,
        "skipped": 2,
        "elegant_rate": 4 / 6,
        "advantage_auroc": 1.0,
        "q_auroc": 1.0,
        "prefers_explored": 4 / 6,
    }
    task0, task1 = result["tasks"]["libero_object/0"], result["tasks"]["libero_object/1"]
    assert (task0["episodes"], task0["advantage_auroc"]) == (4, 1.0)
    assert (task1["episodes"], task1["skipped"], task1["advantage_auroc"]) == (
        2,
        2,
        None,
    )  # both elegant: nothing to separate
    backwards = branch_ranking(path, StatePolicy(), FirstDimCritic(sign=-1.0))["all"]
    assert (backwards["advantage_auroc"], backwards["prefers_explored"]) == (0.0, 2 / 6)


def test_refuses_rollouts_another_policy_recorded_and_a_critic_of_other_chunks(tmp_path):
    path = branch_file(tmp_path)
    with h5py.File(path, "r+") as f:
        f["data/demo_0/actions"][2, 1] += 0.5
    with pytest.raises(UserInputError, match=r"data/demo_0: step 2: the policy acts otherwise than recorded"):
        branch_ranking(path, StatePolicy(), FirstDimCritic())
    with pytest.raises(UserInputError, match="the critic scores chunks of 8 actions but the policy decides 1"):
        branch_ranking(path, StatePolicy(), FirstDimCritic(chunk=8))
