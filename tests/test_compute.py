"""Where networks train and score (`--device`, `--threads`): the options and their refusals, the CPU's
numbers independent of the thread count, artifacts that load on any device, runs that resume on the kind
of device they began on only, and, where torch sees a GPU, training and scoring there."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import torch
from test_critic_data import task_layout, write_annotated
from test_critic_train import UNIT
from test_policy_bc import SMALL, metadata, write_demos

import critics
from base_suites.runtime.compute import ComputeConfig, resolve_device, use_compute
from base_suites.runtime.errors import UserInputError
from critics import train_critic
from elegant.cli import main
from elegant.policies import load_policy, train_policy

CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="torch sees no GPU on this machine")
CRITIC = {"config": UNIT, "progress": False, "steps": 6, "checkpoint_every": 3}


@pytest.fixture(scope="module")
def annotated(tmp_path_factory) -> str:
    return write_annotated(tmp_path_factory.mktemp("compute") / "train.hdf5")


@pytest.fixture(scope="module")
def demos(tmp_path_factory) -> str:
    return write_demos(tmp_path_factory.mktemp("compute") / "demos.hdf5")


def critic_weights(out: str) -> dict[str, torch.Tensor]:
    return torch.load(os.path.join(out, "critic.pt"), map_location="cpu", weights_only=True)


def test_auto_is_a_gpu_when_torch_sees_one_and_the_cpu_otherwise():
    assert resolve_device("auto", "x").type == ("cuda" if torch.cuda.is_available() else "cpu")
    assert resolve_device("cpu", "x") == torch.device("cpu")


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--device", "gpu"], "device must be auto, cpu, cuda or cuda:N, got 'gpu'"),
        (["--threads", "0"], "threads must be a positive integer, got 0"),
    ],
)
def test_malformed_compute_options_are_refused_in_one_line_before_any_work(annotated, tmp_path, capsys, flags, message):
    out = tmp_path / "critic"
    assert main(["train-critic", annotated, "--out", str(out), *flags]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not out.exists()


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a GPU")
def test_a_gpu_that_is_not_there_is_refused_in_one_line(demos, tmp_path, capsys):
    out = tmp_path / "policy"
    assert main(["train-policy", demos, "--out", str(out), "--device", "cuda:1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "sees no GPU; use --device cpu or auto" in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_the_thread_count_sets_torchs_and_leaves_the_numbers_as_they_are(annotated, demos, tmp_path):
    """Threads are a run control: one (the default) and two train bit-identical critics and policies."""
    trained = {}
    for threads in (1, 2):
        assert str(use_compute(ComputeConfig(threads=threads), "x")) == ("cuda" if torch.cuda.is_available() else "cpu")
        assert torch.get_num_threads() == threads
        compute = ComputeConfig(device="cpu", threads=threads)
        critic_dir, policy_dir = str(tmp_path / f"critic{threads}"), str(tmp_path / f"policy{threads}")
        train_critic([annotated], critic_dir, compute=compute, **CRITIC)
        train_policy([demos], policy_dir, epochs=2, compute=compute, **SMALL)
        trained[threads] = critic_dir, policy_dir
    torch.set_num_threads(1)
    (critic1, policy1), (critic2, policy2) = trained[1], trained[2]
    for name, weight in critic_weights(critic1).items():
        assert torch.equal(weight, critic_weights(critic2)[name]), name
    one, two = (json.loads(open(os.path.join(p, "config.json")).read()) for p in (policy1, policy2))
    assert one["model_sha256"] == two["model_sha256"]


def test_artifacts_hold_cpu_tensors_and_record_their_device(annotated, demos, tmp_path):
    critic_dir, policy_dir = str(tmp_path / "critic"), str(tmp_path / "policy")
    summary = train_critic([annotated], critic_dir, compute=ComputeConfig(device="cpu"), **CRITIC)
    train_policy([demos], policy_dir, epochs=1, compute=ComputeConfig(device="cpu"), **SMALL)
    assert summary["device"] == "cpu"
    assert json.loads(open(os.path.join(critic_dir, "critic.json")).read())["training"]["device"] == "cpu"
    assert json.loads(open(os.path.join(policy_dir, "config.json")).read())["training"]["device"] == "cpu"
    policy_state = torch.load(os.path.join(policy_dir, "model.pt"), weights_only=True)
    assert all(t.device.type == "cpu" for t in [*critic_weights(critic_dir).values(), *policy_state.values()])


def test_a_checkpoint_resumes_only_on_the_kind_of_device_it_was_written_on(annotated, demos, tmp_path):
    critic_dir, policy_dir = str(tmp_path / "critic"), str(tmp_path / "policy")
    train_critic([annotated], critic_dir, compute=ComputeConfig(device="cpu"), **CRITIC)
    train_policy([demos], policy_dir, epochs=1, **SMALL)
    for checkpoint in (os.path.join(critic_dir, "checkpoint.pt"), os.path.join(policy_dir, "checkpoint.pt")):
        state = torch.load(checkpoint, weights_only=True)
        assert state["device"] == "cpu"
        torch.save({**state, "device": "cuda (NVIDIA H100 80GB HBM3)"}, checkpoint)
    with pytest.raises(UserInputError, match="written on cuda .* resume it with --device cuda"):
        train_critic([annotated], critic_dir, compute=ComputeConfig(device="cpu"), resume=True, **CRITIC)
    with pytest.raises(UserInputError, match="written on cuda .* resume it with --device cuda"):
        train_policy([demos], policy_dir, epochs=1, resume=True, compute=ComputeConfig(device="cpu"), **SMALL)


def test_the_device_scoring_path_agrees_with_the_cpu_path(annotated, tmp_path):
    """`Critic.to(gpu)` scores through the network's torch forward: run here on the CPU's tensors, it gives
    the NumPy path's Q values to rounding."""
    out = str(tmp_path / "critic")
    train_critic([annotated], out, **CRITIC)
    critic = critics.load(out).bind({"suite": "libero_object", "task_index": 0, "state_layout": task_layout(0)})
    rng = np.random.default_rng(0)
    state = rng.normal(size=sum(s for _, s in task_layout(0))).astype(np.float32)
    actions = rng.uniform(-1, 1, size=(16, 7)).astype(np.float32)
    scaled = np.clip((actions - critic._center) * critic._inv_half, -1, 1)
    on_device = critic._on_device(critic._binding, state[None], scaled[None]).reshape(-1)
    np.testing.assert_allclose(on_device, critic.q(state, actions), rtol=1e-5, atol=1e-5)


def test_a_policy_moved_to_a_device_draws_as_it_did_when_seeded_alike(demos, tmp_path):
    out = str(tmp_path / "policy")
    train_policy([demos], out, epochs=1, **SMALL)
    moved, plain = load_policy(out, seed=3).to("cpu"), load_policy(out, seed=3)
    state = {"state": np.full(8, 0.1)}
    for policy in (moved, plain):
        policy.reset(metadata("libero_object/0"))
    np.testing.assert_array_equal(moved(state), plain(state))
    np.testing.assert_array_equal(moved.sample(state, 4), plain.sample(state, 4))


@CUDA
def test_trained_on_a_gpu_loads_and_scores_on_the_cpu_and_the_reverse(annotated, demos, tmp_path):
    gpu_critic, gpu_policy = str(tmp_path / "gpu_critic"), str(tmp_path / "gpu_policy")
    summary = train_critic([annotated], gpu_critic, compute=ComputeConfig(device="cuda"), **CRITIC)
    train_policy([demos], gpu_policy, epochs=2, compute=ComputeConfig(device="cuda"), **SMALL)
    assert summary["device"].startswith("cuda")
    meta = {"suite": "libero_object", "task_index": 0, "state_layout": task_layout(0)}
    on_cpu, on_gpu = critics.load(gpu_critic).bind(meta), critics.load(gpu_critic).to("cuda").bind(meta)
    rng = np.random.default_rng(0)
    state = rng.normal(size=sum(s for _, s in task_layout(0)))
    actions = rng.uniform(-1, 1, size=(16, 7))
    np.testing.assert_allclose(on_gpu.q(state, actions), on_cpu.q(state, actions), rtol=1e-4, atol=1e-4)
    cpu_policy, cuda_policy = load_policy(gpu_policy), load_policy(gpu_policy).to("cuda")
    for policy in (cpu_policy, cuda_policy):
        policy.reset(metadata("libero_object/0"))
    obs = {"state": np.full(8, 0.1)}
    np.testing.assert_allclose(cuda_policy(obs), cpu_policy(obs), atol=1e-4)
    assert cuda_policy.sample(obs, 4).shape == (4, 7)
