"""The policy protocol and its adapters: callables, LeRobot-style policies, TorchRL modules."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tensordict.nn import (
    NormalParamExtractor,
    ProbabilisticTensorDictModule,
    ProbabilisticTensorDictSequential,
    TensorDictModule,
)
from torch import nn

from base_suites.runtime.errors import UserInputError
from elegant.policies import (
    ACTION_DIM,
    TORCHRL_LIBERO_STATE,
    CallablePolicy,
    GaussianCandidates,
    LayoutSlice,
    LeRobotPolicy,
    Policy,
    TorchRLPolicy,
    as_policy,
    lerobot_libero_state,
)

torch.set_num_threads(1)

LAYOUT = [
    ["robot0_eef_pos", 3],
    ["robot0_eef_quat", 4],
    ["robot0_gripper_qpos", 2],
    ["robot0_joint_pos", 7],
    ["bowl_1/pos", 3],
]
METADATA = {"suite": "libero_object", "task_index": 0, "instruction": "pick up the bowl", "state_layout": LAYOUT}


def obs_of(seed: int) -> dict[str, np.ndarray]:
    return {"state": np.random.default_rng(seed).normal(size=19)}


def linear_policy(obs):
    return np.tanh(obs["state"][:7])


# ---- Gaussian candidates -------------------------------------------------------------------------
def test_gaussian_candidates_keep_action_first_clip_and_reproduce():
    action = np.array([0.95, -0.95, 0.0, 0.5, -0.5, 0.2, 1.0])
    a = GaussianCandidates(scale=0.5, seed=3)(action, 64)
    assert a.shape == (64, 7)
    np.testing.assert_array_equal(a[0], action)
    assert a.min() >= -1.0 and a.max() <= 1.0
    assert (a[1:, 0] == 1.0).any() and (a[1:, 1] == -1.0).any()  # perturbations past the bounds were clipped
    np.testing.assert_array_equal(a, GaussianCandidates(scale=0.5, seed=3)(action, 64))
    assert not np.array_equal(a, GaussianCandidates(scale=0.5, seed=4)(action, 64))
    with pytest.raises(UserInputError):
        GaussianCandidates(scale=0.1)(action, 0)
    with pytest.raises(UserInputError):
        GaussianCandidates(scale=-1.0)


# ---- plain callables -----------------------------------------------------------------------------
def test_callable_adapter_clips_and_candidate_zero_is_the_action():
    policy = as_policy(lambda obs: np.full(7, 3.0) * np.sign(obs["state"][:7]), seed=1)
    assert isinstance(policy, CallablePolicy) and isinstance(policy, Policy)
    obs = obs_of(0)
    action = policy(obs)
    assert action.shape == (7,) and set(np.abs(action)) == {1.0}
    cands = policy.sample(obs, 16)
    np.testing.assert_array_equal(cands[0], action)
    assert cands.min() >= -1.0 and cands.max() <= 1.0


def test_callable_adapter_reseeds_and_does_not_step_twice():
    calls = []

    def counted(obs):
        calls.append(1)
        return linear_policy(obs)

    policy = as_policy(counted, noise_scale=0.2, seed=0)
    obs = obs_of(1)
    policy.reset(METADATA, seed=7)
    policy(obs)
    first = policy.sample(obs, 8)
    assert len(calls) == 1  # sampling right after the step reuses its action
    policy.sample(obs_of(2), 4)
    assert len(calls) == 2  # a new observation is a new step
    policy.reset(METADATA, seed=7)
    policy(obs)
    np.testing.assert_array_equal(policy.sample(obs, 8), first)
    policy.reset(METADATA, seed=8)
    assert not np.array_equal(policy.sample(obs, 8), first)


def test_callable_adapter_refuses_wrong_action_shape_and_unsupported_objects():
    with pytest.raises(UserInputError, match=r"shape \(6,\)"):
        as_policy(lambda obs: np.zeros(6))(obs_of(0))
    with pytest.raises(UserInputError, match="cannot use a int as a policy"):
        as_policy(42)


def test_callable_with_own_sample_and_reset_is_delegated():
    class Stochastic:
        def __init__(self):
            self.resets = 0

        def __call__(self, obs):
            return np.zeros(7)

        def sample(self, obs, n):
            return np.full((n, 7), 2.0)

        def reset(self):
            self.resets += 1

    inner = Stochastic()
    policy = as_policy(inner)
    np.testing.assert_array_equal(policy.sample(obs_of(0), 3), np.ones((3, 7)))  # its own sampler, clipped
    policy.reset(METADATA)
    assert inner.resets == 1
    with pytest.raises(UserInputError, match=r"expected \(3, 7\)"):
        CallablePolicy(
            type("Bad", (), {"__call__": lambda s, o: np.zeros(7), "sample": lambda s, o, n: np.zeros((n, 6))})()
        ).sample(obs_of(0), 3)


def test_full_policies_pass_through():
    policy = as_policy(linear_policy)
    assert as_policy(policy) is policy


# ---- LeRobot-style -------------------------------------------------------------------------------
class QueuePolicy:
    """Same interface as LeRobot policies: select_action pops a queue of action chunks; reset clears it."""

    def __init__(self):
        self.queue: list[torch.Tensor] = []
        self.batches: list[dict] = []

    def select_action(self, batch):
        self.batches.append(batch)
        if not self.queue:
            state = batch["observation.state"]
            self.queue = [torch.tanh(state[:, :7]) * (k + 1) / 3 for k in range(3)]
        return self.queue.pop(0)

    def reset(self):
        self.queue = []


def test_lerobot_adapter_batches_state_and_task_and_resets():
    inner = QueuePolicy()
    policy = as_policy(inner, seed=0)
    assert isinstance(policy, LeRobotPolicy)
    obs = obs_of(3)
    policy.reset(METADATA)
    a0 = policy(obs)
    batch = inner.batches[-1]
    assert batch["observation.state"].shape == (1, 19) and batch["observation.state"].dtype == torch.float32
    assert batch["task"] == ["pick up the bowl"]
    np.testing.assert_allclose(a0, np.tanh(obs["state"][:7]) / 3, atol=1e-6)
    np.testing.assert_array_equal(policy.sample(obs, 5)[0], a0)
    assert len(inner.queue) == 2  # sampling did not pop the queue
    a1 = policy(obs)
    np.testing.assert_allclose(a1, np.clip(np.tanh(obs["state"][:7]) * 2 / 3, -1, 1), atol=1e-6)
    policy.reset(METADATA)
    assert inner.queue == []
    np.testing.assert_allclose(policy(obs), a0, atol=1e-6)


def test_lerobot_adapter_passes_images_and_mapped_state():
    inner = QueuePolicy()
    policy = LeRobotPolicy(inner, state_fn=lerobot_libero_state)
    policy.reset(METADATA)
    obs = {"state": obs_of(4)["state"], "agentview": np.full((8, 8, 3), 255, dtype=np.uint8)}
    policy(obs)
    batch = inner.batches[-1]
    assert batch["observation.images.image"].shape == (1, 3, 8, 8)
    assert float(batch["observation.images.image"].max()) == 1.0
    assert batch["observation.state"].shape == (1, 8)


def test_lerobot_adapter_feeds_the_vla_observation_under_lerobots_libero_keys():
    inner = QueuePolicy()
    policy = LeRobotPolicy(inner)
    policy.reset(METADATA)
    image, wrist = np.full((8, 8, 3), 255, dtype=np.uint8), np.zeros((8, 8, 3), dtype=np.uint8)
    vla_state = np.arange(8, dtype=np.float64)
    policy({"state": obs_of(4)["state"], "image": image, "wrist_image": wrist, "vla_state": vla_state})
    batch = inner.batches[-1]
    assert (
        float(batch["observation.images.image"].max()) == 1.0 and float(batch["observation.images.image2"].max()) == 0
    )
    np.testing.assert_array_equal(batch["observation.state"].numpy()[0], vla_state)
    assert batch["task"] == ["pick up the bowl"] and "agentview" not in str(sorted(batch))


def test_state_selection_by_layout_name():
    state = np.arange(19, dtype=np.float64)
    np.testing.assert_array_equal(TORCHRL_LIBERO_STATE(state, METADATA), np.arange(9))
    np.testing.assert_array_equal(LayoutSlice("bowl_1/pos", "robot0_eef_pos")(state, METADATA), [16, 17, 18, 0, 1, 2])
    half_turn_z = np.zeros(19)
    half_turn_z[3:7] = [0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)]  # (x, y, z, w): 90 deg about z
    np.testing.assert_allclose(lerobot_libero_state(half_turn_z, METADATA)[3:6], [0.0, 0.0, np.pi / 2])
    np.testing.assert_array_equal(
        lerobot_libero_state(np.r_[np.zeros(6), 1.0, np.zeros(12)], METADATA)[3:6], np.zeros(3)
    )
    with pytest.raises(UserInputError, match="call reset"):
        TORCHRL_LIBERO_STATE(state, None)
    with pytest.raises(UserInputError, match="no entries.*plate"):
        LayoutSlice("plate/pos")(state, METADATA)


# ---- TorchRL -------------------------------------------------------------------------------------
def test_torchrl_deterministic_module():
    torch.manual_seed(0)
    linear = nn.Linear(19, 7)
    module = TensorDictModule(linear, in_keys=[("observation", "state")], out_keys=["action"])
    policy = as_policy(module, noise_scale=0.3, seed=2)
    assert isinstance(policy, TorchRLPolicy) and not policy.stochastic
    obs = obs_of(5)
    action = policy(obs)
    with torch.no_grad():
        expected = linear(torch.as_tensor(obs["state"], dtype=torch.float32)).clamp(-1, 1).double().numpy()
    np.testing.assert_allclose(action, expected, atol=1e-6)
    cands = policy.sample(obs, 10)
    np.testing.assert_array_equal(cands[0], action)
    assert np.abs(cands[1:] - action).max() > 0


def test_torchrl_module_on_selected_state_reads_instruction():
    seen = []

    class Reader(nn.Module):
        def forward(self, state, instruction):
            seen.append(instruction)
            return state[..., :7].clone()

    module = TensorDictModule(Reader(), in_keys=[("observation", "state"), "language_instruction"], out_keys=["action"])
    policy = TorchRLPolicy(module, state_fn=TORCHRL_LIBERO_STATE)
    policy.reset(METADATA)
    obs = {"state": np.linspace(-0.5, 0.5, 19)}
    np.testing.assert_allclose(policy(obs), obs["state"][:7], atol=1e-6)
    assert seen == ["pick up the bowl"]


def test_torchrl_probabilistic_module_samples_its_distribution_reproducibly():
    torch.manual_seed(0)
    net = nn.Sequential(nn.Linear(19, 14), NormalParamExtractor())
    module = ProbabilisticTensorDictSequential(
        TensorDictModule(net, in_keys=[("observation", "state")], out_keys=["loc", "scale"]),
        ProbabilisticTensorDictModule(
            in_keys=["loc", "scale"], out_keys=["action"], distribution_class=torch.distributions.Normal
        ),
    )
    policy = as_policy(module, seed=11)
    assert policy.stochastic
    obs = obs_of(6)
    with torch.no_grad():
        loc = net(torch.as_tensor(obs["state"], dtype=torch.float32))[0].clamp(-1, 1).double().numpy()
    action = policy(obs)
    np.testing.assert_allclose(action, loc, atol=1e-6)  # acts with the distribution's deterministic sample
    global_state = torch.random.get_rng_state()
    cands = policy.sample(obs, 32)
    assert torch.equal(global_state, torch.random.get_rng_state())  # the global torch RNG is left alone
    np.testing.assert_array_equal(cands[0], action)
    assert cands.min() >= -1.0 and cands.max() <= 1.0
    assert cands[1:].std(0).min() > 0.05  # drawn from the distribution, not a copy of the mean
    policy.reset(seed=11)
    policy(obs)
    np.testing.assert_array_equal(policy.sample(obs, 32), cands)


class SeededDraws:
    """A stochastic callable that takes seeds: candidates are its own repeated draws."""

    stochastic = True

    def __init__(self):
        self.rng = np.random.default_rng(0)
        self.seeds = []

    def __call__(self, obs):
        return self.rng.uniform(-1, 1, ACTION_DIM)

    def reset(self, metadata=None, *, seed=None):
        self.seeds.append(seed)
        self.rng = np.random.default_rng(seed)


def test_a_stochastic_callable_gives_its_own_draws_as_candidates_and_receives_the_episode_seed():
    inner = SeededDraws()
    policy = as_policy(inner)
    assert policy.candidate_source == "repeated calls"
    policy.reset(METADATA, seed=5)
    obs = obs_of(1)
    action = policy(obs)
    candidates = policy.sample(obs, 4)
    np.testing.assert_array_equal(candidates[0], action)
    assert len({tuple(c) for c in candidates}) == 4 and inner.seeds == [5]
    policy.reset(METADATA, seed=5)
    np.testing.assert_array_equal(policy(obs), action)  # the seed reached the policy: the draws repeat
    assert as_policy(lambda o: np.zeros(ACTION_DIM)).candidate_source == "Gaussian noise"
