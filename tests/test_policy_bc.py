"""BC-GMM policy: training on a tiny synthetic dataset, resume, the saved artifact and its refusals."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import torch

from annotations import Demo, DemoWriter
from base_suites.runtime.errors import UserInputError
from elegant.policies import BCPolicy, Policy, as_policy, load_policy, train_policy
from elegant.policies.bc_config import BCConfig
from elegant.policies.bc_data import load_demos

torch.set_num_threads(1)

LAYOUTS = {
    "libero_object/0": [["robot0_eef_pos", 3], ["robot0_gripper_qpos", 2], ["bowl_1/pos", 3]],
    "libero_object/1": [["robot0_eef_pos", 3], ["robot0_gripper_qpos", 2]],
}
GOALS = {"libero_object/0": np.array([0.3, -0.2, 0.1]), "libero_object/1": np.array([-0.3, 0.2, 0.3])}
# a small network acting one step at a time without input noise (the defaults are the recipe's chunked,
# noise-trained policy); each test sets what it examines on top
SMALL = {
    "config": BCConfig(history=2, batch_size=32, hidden=(64, 64), modes=3, chunk=1, obs_noise=0.0),
    "progress": False,
}


def expert(state: np.ndarray, key: str) -> np.ndarray:
    """Move towards the task's goal; close the gripper once above 0.2 m: a function of state and task."""
    action = np.zeros(7)
    action[:3] = np.tanh(4.0 * (GOALS[key] - state[:3]))
    action[6] = 1.0 if state[2] > 0.2 else -1.0
    return action


def write_demos(
    path, *, demos_per_task: int = 5, steps: int = 30, seed: int = 0, layouts=LAYOUTS, failures: int = 0
) -> str:
    """`failures`: the last this many demos of each task are marked as failed episodes."""
    rng = np.random.default_rng(seed)
    writer = DemoWriter(str(path), {"env_args": {}, "problem_info": {}})
    for key, layout in layouts.items():
        suite, index = key.split("/")
        width = sum(s for _, s in layout)
        for d in range(demos_per_task):
            state = rng.uniform(-0.4, 0.4, size=width)
            obs, actions = [], []
            for _ in range(steps):
                obs.append(state.copy())
                actions.append(expert(state, key))
                state = state.copy()
                state[:3] += 0.05 * actions[-1][:3] + rng.normal(0, 0.005, 3)
            obs, actions = np.array(obs), np.array(actions)
            attrs = {
                "suite": suite,
                "task_index": int(index),
                "task_name": key,
                "success": d < demos_per_task - failures,
            }
            demo = Demo(
                f"demo_{d}",
                actions,
                np.zeros((steps, 3)),
                obs,
                np.roll(obs, -1, 0),
                np.zeros(steps),
                np.eye(steps)[-1],
                attrs,
            )
            writer.append(demo, state_layout=layout)
    return writer.finish()


@pytest.fixture(scope="module")
def demos(tmp_path_factory) -> str:
    return write_demos(tmp_path_factory.mktemp("demos") / "demos.hdf5")


def metadata(key: str, layout=None) -> dict:
    suite, index = key.split("/")
    return {"suite": suite, "task_index": int(index), "instruction": key, "state_layout": layout or LAYOUTS[key]}


def fit_error(policy: BCPolicy, seed: int = 99) -> tuple[float, float]:
    """On fresh expert episodes of both tasks: the mean squared error of the arm's six action dims, and
    how often the gripper command has the expert's sign. Kept apart because the gripper flips at a
    threshold: a few steps on the wrong side of it would swamp a single squared error."""
    rng = np.random.default_rng(seed)
    arm_errors, gripper_agrees = [], []
    for key, layout in LAYOUTS.items():
        for _ in range(3):
            policy.reset(metadata(key))
            state = rng.uniform(-0.4, 0.4, size=sum(s for _, s in layout))
            for _ in range(30):
                target, action = expert(state, key), policy({"state": state})
                arm_errors.append(np.mean((action[:6] - target[:6]) ** 2))
                gripper_agrees.append(np.sign(action[6]) == np.sign(target[6]))
                state = state.copy()
                state[:3] += 0.05 * target[:3]
    return float(np.mean(arm_errors)), float(np.mean(gripper_agrees))


def test_training_fits_the_expert_far_better_than_initialisation(demos, tmp_path):
    trained = train_policy([demos], str(tmp_path / "bc"), epochs=40, lr=1e-2, seed=0, **SMALL)
    train_policy([demos], str(tmp_path / "init"), epochs=1, lr=0.0, seed=0, **SMALL)
    assert trained["tasks"] == sorted(LAYOUTS) and trained["num_samples"] == 2 * 5 * 30
    assert trained["loss_history"][-1] < trained["loss_history"][0] - 3.0
    (arm_before, gripper_before), (arm_after, gripper_after) = (
        fit_error(load_policy(str(tmp_path / d))) for d in ("init", "bc")
    )
    assert arm_after < 0.3 * arm_before and gripper_after > 0.85 > gripper_before, (
        arm_before,
        arm_after,
        gripper_before,
        gripper_after,
    )


def test_resume_after_a_crash_equals_an_uninterrupted_run(demos, tmp_path):
    full = train_policy([demos], str(tmp_path / "full"), epochs=3, seed=5, **SMALL)

    def crash(info):
        if info["epoch"] == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train_policy([demos], str(tmp_path / "cut"), epochs=3, seed=5, on_epoch_end=crash, **SMALL)
    assert not os.path.exists(tmp_path / "cut" / "model.pt")
    resumed = train_policy([demos], str(tmp_path / "cut"), epochs=3, seed=5, resume=True, **SMALL)
    assert resumed["resumed_from_epoch"] == 2
    assert resumed["loss_history"] == full["loss_history"]
    a = torch.load(tmp_path / "full" / "model.pt", weights_only=True)
    b = torch.load(tmp_path / "cut" / "model.pt", weights_only=True)
    assert all(torch.equal(a[k], b[k]) for k in a)
    other_seed = train_policy([demos], str(tmp_path / "other"), epochs=1, seed=6, **SMALL)
    assert other_seed["loss_history"][0] != full["loss_history"][0]
    with pytest.raises(UserInputError, match="cannot resume, field 'config.lr' was 0.001 and is now 0.5"):
        train_policy([demos], str(tmp_path / "cut"), epochs=3, seed=5, lr=0.5, resume=True, **SMALL)
    (tmp_path / "cut" / "checkpoint.pt").write_bytes(b"truncated")
    with pytest.raises(UserInputError, match="unreadable checkpoint"):
        train_policy([demos], str(tmp_path / "cut"), epochs=3, seed=5, resume=True, **SMALL)


@pytest.fixture(scope="module")
def policy_dir(demos, tmp_path_factory) -> str:
    out = str(tmp_path_factory.mktemp("policy") / "bc")
    train_policy([demos], out, epochs=2, seed=1, **SMALL)
    return out


def test_policy_protocol_actions_and_seeded_samples(policy_dir):
    policy = load_policy(policy_dir, seed=3)
    assert isinstance(policy, Policy) and as_policy(policy) is policy
    key = "libero_object/0"
    obs = {"state": np.linspace(-0.3, 0.3, 8)}
    policy.reset(metadata(key), seed=3)
    action = policy(obs)
    assert action.shape == (7,) and action.dtype == np.float64 and np.abs(action).max() <= 1.0
    np.testing.assert_array_equal(policy(obs), policy(obs))  # deterministic at evaluation
    samples = policy.sample(obs, 16)
    assert samples.shape == (16, 7) and np.abs(samples).max() <= 1.0 and samples.std(0).max() > 0
    policy.reset(metadata(key), seed=3)
    policy(obs), policy(obs), policy(obs)
    np.testing.assert_array_equal(policy.sample(obs, 16), samples)
    policy.reset(metadata(key), seed=4)
    assert not np.array_equal(policy.sample(obs, 16), samples)


def test_sampling_policy_acts_by_seeded_draws_apart_from_the_candidates(policy_dir):
    key, obs = "libero_object/0", {"state": np.linspace(-0.3, 0.3, 8)}
    mode = load_policy(policy_dir)
    mode.reset(metadata(key), seed=3)
    policy = load_policy(policy_dir, act="sample")
    assert policy.act == "sample"

    def first_actions(seed: int, with_candidates: bool) -> list[np.ndarray]:
        policy.reset(metadata(key), seed=seed)
        actions = []
        for _ in range(3):
            actions.append(policy(obs))
            if with_candidates:
                policy.sample(obs, 16)
        return actions

    drawn = first_actions(3, with_candidates=False)
    assert not np.array_equal(drawn[0], mode(obs))  # a draw, not the most likely component's mean
    assert not np.array_equal(drawn[0], drawn[1])  # a new draw at every decision
    assert np.abs(np.array(drawn)).max() <= 1.0
    np.testing.assert_array_equal(
        first_actions(3, with_candidates=True), drawn
    )  # candidates draw from their own stream
    assert not np.array_equal(first_actions(4, with_candidates=False)[0], drawn[0])


def test_component_act_executes_the_mean_of_a_component_drawn_by_weight(policy_dir):
    """LIBERO's low_eval_noise: every executed plan is exactly one component's mean, components are
    drawn in proportion to their weights, and the draws are seeded."""
    key, obs = "libero_object/0", {"state": np.linspace(-0.3, 0.3, 8)}
    policy = load_policy(policy_dir, act="component")
    policy.reset(metadata(key), seed=5)
    policy.observe(obs)
    with torch.inference_mode():
        logits, means, _ = policy._distribution()
    weights, means = torch.softmax(logits[0], -1).numpy(), means[0].double().numpy()
    picks = []
    for _ in range(400):
        action = policy.plan(obs).reshape(-1)
        matches = np.flatnonzero(np.all(np.isclose(means, action, atol=1e-6), axis=1))
        assert matches.size >= 1  # a component's mean, no Gaussian noise on top
        picks.append(matches[0])  # the history holds only `obs`, so every draw sees the same mixture
    assert weights.max() < 0.9  # a mixture with more than one component in use, or the check below says little
    frequencies = np.bincount(picks, minlength=len(weights)) / len(picks)
    np.testing.assert_allclose(frequencies, weights, atol=0.08)
    policy.reset(metadata(key), seed=5)
    again = policy(obs)
    policy.reset(metadata(key), seed=5)
    np.testing.assert_array_equal(policy(obs), again)


def test_unknown_policy_act_is_refused(policy_dir):
    with pytest.raises(UserInputError, match="unknown policy act 'mean'; expected one of: mode, sample, component"):
        load_policy(policy_dir, act="mean")


def test_sample_does_not_advance_the_history(policy_dir):
    key, rng = "libero_object/1", np.random.default_rng(0)
    first, second = ({"state": rng.normal(size=5)} for _ in range(2))
    policy = load_policy(policy_dir)
    policy.reset(metadata(key))
    policy(first)
    policy.sample(first, 8)
    with_sampling = policy(second)
    policy.reset(metadata(key))
    policy(first)
    np.testing.assert_array_equal(policy(second), with_sampling)
    policy.reset(metadata(key))
    policy(second)
    assert not np.array_equal(policy(second), with_sampling)  # the history does matter


def test_policy_refuses_other_layouts_tasks_and_missing_reset(policy_dir):
    policy = load_policy(policy_dir)
    wrong = [["robot0_eef_pos", 3], ["robot0_gripper_qpos", 2], ["plate_1/pos", 3]]
    with pytest.raises(UserInputError, match=f"{policy_dir}: observation layout of env task libero_object/0 differs"):
        policy.reset(metadata("libero_object/0", wrong))
    with pytest.raises(UserInputError, match=f"{policy_dir}: env task .libero_object/7. is not among the tasks"):
        policy.reset(metadata("libero_object/7", LAYOUTS["libero_object/1"]))
    policy.reset()
    with pytest.raises(UserInputError, match=r"needs reset\(env.metadata\)"):
        policy({"state": np.zeros(8)})
    policy.reset(metadata("libero_object/1"))
    with pytest.raises(UserInputError, match=r"expects \(5,\)"):
        policy({"state": np.zeros(8)})


def test_load_refuses_missing_and_corrupt_dirs(policy_dir, tmp_path):
    with pytest.raises(UserInputError, match="no such policy directory"):
        load_policy(str(tmp_path / "nowhere"))
    broken = tmp_path / "broken"
    broken.mkdir()
    for name in ("model.pt", "config.json"):
        (broken / name).write_bytes(open(os.path.join(policy_dir, name), "rb").read())
    with open(broken / "model.pt", "ab") as fh:
        fh.write(b"x")
    with pytest.raises(UserInputError, match="does not match config.json"):
        load_policy(str(broken))
    good = json.load(open(os.path.join(policy_dir, "config.json")))
    (broken / "model.pt").write_bytes(open(os.path.join(policy_dir, "model.pt"), "rb").read())
    (broken / "config.json").write_text(json.dumps({k: v for k, v in good.items() if k != "features"}))
    with pytest.raises(UserInputError, match="config.json: missing field 'features'"):
        load_policy(str(broken))
    (broken / "config.json").write_text("{not json")
    with pytest.raises(UserInputError, match="corrupt policy config"):
        load_policy(str(broken))
    (broken / "config.json").write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(UserInputError, match="field 'format'"):
        load_policy(str(broken))
    os.remove(broken / "model.pt")
    with pytest.raises(UserInputError, match="missing model.pt"):
        load_policy(str(broken))


def test_config_records_inputs_and_versions(policy_dir):
    config = json.load(open(os.path.join(policy_dir, "config.json")))
    assert config["features"]["encoder"]["layouts"] == LAYOUTS
    assert set(config["features"]["normalization"]) == set(LAYOUTS)
    assert config["features"]["history"] == 2
    assert {"torch", "numpy", "libero-elegant"} <= set(config["versions"])


def test_training_refuses_bad_input(demos, tmp_path):
    with pytest.raises(UserInputError, match="epochs must be a positive integer"):
        train_policy([demos], str(tmp_path / "x"), epochs=0, progress=False)
    with pytest.raises(UserInputError, match="obs_noise must be >= 0"):
        train_policy([demos], str(tmp_path / "x"), epochs=1, obs_noise=-0.1, progress=False)
    with pytest.raises(UserInputError, match="non-empty list"):
        train_policy([], str(tmp_path / "x"), epochs=1, progress=False)
    with pytest.raises(UserInputError, match="no such file"):
        train_policy([str(tmp_path / "missing.hdf5")], str(tmp_path / "x"), epochs=1, progress=False)
    other = {"libero_object/1": [["robot0_eef_pos", 3], ["robot0_gripper_qpos", 2], ["plate_1/pos", 3]]}
    clash = write_demos(tmp_path / "clash.hdf5", demos_per_task=1, steps=3, layouts=other)
    with pytest.raises(UserInputError, match=r"state_layouts\['libero_object/1'\] differs"):
        train_policy([demos, clash], str(tmp_path / "x"), epochs=1, progress=False)
    assert not (tmp_path / "x").exists()  # refused inputs leave no output directory


def test_training_that_diverges_stops_before_saving_non_finite_weights(demos, tmp_path):
    out = tmp_path / "diverged"
    with pytest.raises(UserInputError, match="train-policy: training diverged at epoch 1 .*nothing was saved"):
        train_policy([demos], str(out), epochs=2, lr=1e30, seed=0, **SMALL)
    assert not (out / "model.pt").exists() and not (out / "checkpoint.pt").exists()


def test_train_policy_cli_passes_its_options_and_refuses_in_one_line(tmp_path, capsys):
    from elegant.cli import main

    data = write_demos(tmp_path / "mixed.hdf5", demos_per_task=3, steps=6, failures=1)
    out = tmp_path / "cli"
    args = [
        "train-policy",
        data,
        "--out",
        str(out),
        "--epochs",
        "1",
        "--seed",
        "3",
        "--history",
        "2",
        "--modes",
        "2",
        "--chunk",
        "2",
        "--successful-only",
        "--no-task-film",
        "--obs-noise",
        "0.1",
    ]
    assert main(args) == 0
    training = json.load(open(out / "config.json"))["training"]
    config = training["config"]
    assert (config["seed"], config["history"], config["modes"], config["chunk"], config["obs_noise"]) == (
        3,
        2,
        2,
        2,
        0.1,
    )
    assert config["task_film"] is False and training["successful_only"] is True
    assert training["num_samples"] == 2 * 2 * 6  # the failed demo of each task was left out
    capsys.readouterr()
    assert main(["train-policy", data, "--out", str(tmp_path / "bad"), "--obs-noise", "-1"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        "elegant train-policy: error: train_policy: obs_noise must be >= 0, got -1.0"
    ]


def test_chunk_targets_are_the_next_actions_with_the_last_repeated_past_the_end():
    from annotations import TaskFeatureEncoder
    from elegant.policies.bc_data import DemoSet, Episode
    from elegant.policies.bc_features import BCFeatures
    from elegant.policies.bc_train import _Windows

    layout = {"libero_object/1": LAYOUTS["libero_object/1"]}
    actions = np.arange(35, dtype=np.float32).reshape(5, 7)
    data = DemoSet(layout, [Episode("libero_object/1", np.zeros((5, 5)), actions)])
    stats = {"libero_object/1": {"mean": np.zeros(5), "std": np.ones(5)}}
    windows = _Windows(data, BCFeatures(TaskFeatureEncoder(layout), stats, history=2), chunk=3)
    _, targets = windows.batch(torch.tensor([0, 3, 4]))
    expected = np.stack([actions[[0, 1, 2]], actions[[3, 4, 4]], actions[[4, 4, 4]]]).reshape(3, 21)
    np.testing.assert_array_equal(targets.numpy(), expected)


def test_observation_noise_jitters_only_the_states_a_task_has_and_is_seeded():
    from annotations import TaskFeatureEncoder
    from elegant.policies.bc_data import DemoSet, Episode
    from elegant.policies.bc_features import BCFeatures
    from elegant.policies.bc_train import _Windows

    # libero_object/1 has 5 state dims, padded to the 8 of libero_object/0
    data = DemoSet(
        LAYOUTS,
        [
            Episode("libero_object/0", np.zeros((4, 8)), np.zeros((4, 7), np.float32)),
            Episode("libero_object/1", np.zeros((4, 5)), np.zeros((4, 7), np.float32)),
        ],
    )
    stats = {
        k: {"mean": np.zeros(sum(s for _, s in v)), "std": np.ones(sum(s for _, s in v))} for k, v in LAYOUTS.items()
    }
    windows = _Windows(data, BCFeatures(TaskFeatureEncoder(LAYOUTS), stats, history=2))
    index = torch.arange(8)
    clean, _ = windows.batch(index)
    noisy, _ = windows.batch(index, 0.5, torch.Generator().manual_seed(0))
    again, _ = windows.batch(index, 0.5, torch.Generator().manual_seed(0))
    torch.testing.assert_close(noisy, again)
    states = (noisy - clean)[:, :16].reshape(8, 2, 8)  # (sample, history, state slot)
    assert (states[:4] != 0).all()  # every slot of the full layout, in both history states
    assert (states[4:, :, :5] != 0).all() and (states[4:, :, 5:] == 0).all()  # padding stays zero
    assert 0.3 < states[:4].std().item() < 0.7
    torch.testing.assert_close(noisy[:, 16:], clean[:, 16:])  # the task one-hot is never jittered


def test_a_chunked_policy_decides_every_chunk_steps_and_still_fits_the_expert(demos, tmp_path):
    out = str(tmp_path / "chunked")
    train_policy([demos], out, epochs=40, lr=1e-2, seed=0, chunk=3, **SMALL)
    policy = load_policy(out)
    assert policy.chunk == 3 and json.load(open(os.path.join(out, "config.json")))["model"]["action_dim"] == 21
    arm_error, gripper_agreement = fit_error(policy)
    assert arm_error < 0.02 and gripper_agreement > 0.85, (arm_error, gripper_agreement)
    key, rng = "libero_object/0", np.random.default_rng(1)
    observations = [{"state": rng.uniform(-0.4, 0.4, 8)} for _ in range(6)]
    policy.reset(metadata(key), seed=0)
    executed = [policy(obs) for obs in observations]
    policy.reset(metadata(key), seed=0)
    first = policy.plan(observations[0])
    candidates = policy.sample_plans(observations[0], 16)  # does not step the history again
    policy.observe(observations[1]), policy.observe(observations[2])
    second = policy.plan(observations[3])
    np.testing.assert_array_equal(np.array(executed), np.concatenate([first, second[:3]]))
    assert first.shape == (3, 7) and candidates.shape == (16, 3, 7) and np.abs(candidates).max() <= 1.0
    assert policy.sample(observations[3], 4).shape == (4, 7)


def test_a_policy_saved_before_chunking_loads_as_one_action_per_decision(policy_dir, tmp_path):
    old = tmp_path / "old"
    old.mkdir()
    config = json.load(open(os.path.join(policy_dir, "config.json")))
    del config["model"]["chunk"]
    (old / "config.json").write_text(json.dumps(config))
    (old / "model.pt").write_bytes(open(os.path.join(policy_dir, "model.pt"), "rb").read())
    policy = load_policy(str(old))
    assert policy.chunk == 1
    policy.reset(metadata("libero_object/1"))
    assert policy.plan({"state": np.zeros(5)}).shape == (1, 7)


def test_task_film_starts_as_the_plain_mlp_and_conditions_every_layer_on_the_task():
    from elegant.policies.bc_model import BCNet

    torch.manual_seed(0)
    film, plain = BCNet(12, hidden=(16, 16), modes=2, task_dim=2), BCNet(12, hidden=(16, 16), modes=2)
    plain.load_state_dict({k: v for k, v in film.state_dict().items() if not k.startswith("film.")})
    x = torch.randn(5, 12)
    assert all(torch.equal(a, b) for a, b in zip(film(x), plain(x)))
    with torch.no_grad():  # the one-hot's input weights zeroed: only FiLM can still tell the tasks apart
        for net in (film, plain):
            net.trunk[0].weight[:, -2:] = 0.0
        for layer in film.film:
            layer.weight.normal_()
    first, second = x.clone(), x.clone()
    first[:, -2:], second[:, -2:] = torch.tensor([1.0, 0.0]), torch.tensor([0.0, 1.0])
    assert torch.equal(plain(first)[1], plain(second)[1])
    assert not torch.allclose(film(first)[1], film(second)[1])


def test_policies_record_their_task_conditioning_and_older_ones_load_without_it(policy_dir, tmp_path):
    assert json.load(open(os.path.join(policy_dir, "config.json")))["model"]["task_dim"] == len(LAYOUTS)
    assert load_policy(policy_dir).net.film is not None
    out = tmp_path / "plain"
    train_policy(
        [write_demos(tmp_path / "d.hdf5", demos_per_task=2, steps=5)], str(out), epochs=1, task_film=False, **SMALL
    )
    config = json.load(open(out / "config.json"))
    assert config["model"]["task_dim"] == 0
    del config["model"]["task_dim"]  # as written before FiLM existed
    (out / "config.json").write_text(json.dumps(config))
    policy = load_policy(str(out))
    assert policy.net.film is None
    policy.reset(metadata("libero_object/1"))
    assert policy({"state": np.zeros(5)}).shape == (7,)


def test_successful_only_clones_the_successes_and_a_resume_must_agree(tmp_path):
    path = write_demos(tmp_path / "mixed.hdf5", demos_per_task=4, failures=1, steps=10)
    assert len(load_demos([path]).episodes) == 8
    assert len(load_demos([path], successful_only=True).episodes) == 6
    out = str(tmp_path / "policy")
    summary = train_policy([path], out, epochs=1, **SMALL)  # the default, as LIBERO's datasets hold
    assert summary["num_demos"] == 6
    assert json.load(open(os.path.join(out, "config.json")))["training"]["successful_only"] is True
    with pytest.raises(UserInputError, match="cannot resume"):
        train_policy([path], out, epochs=1, resume=True, successful_only=False, **SMALL)
    every = train_policy([path], str(tmp_path / "every"), epochs=1, successful_only=False, **SMALL)
    assert every["num_demos"] == 8


def test_evaluation_agents_act_as_asked_in_every_worker(policy_dir):
    """`build_agent` is what each evaluation worker calls: the act reaches the policy it loads."""
    from elegant.evaluation.config import EvalConfig
    from elegant.evaluation.runner import build_agent

    base = EvalConfig().with_settings(mode="base")
    assert build_agent(policy_dir, None, base).policy.act == "mode"
    assert build_agent(policy_dir, None, base.with_settings(policy_act="sample")).policy.act == "sample"


def test_log_prob_plans_is_the_mixtures_density_and_does_not_advance_the_history(policy_dir):
    from elegant.policies.bc_model import gmm_nll

    key, rng = "libero_object/1", np.random.default_rng(0)
    first, second = ({"state": rng.normal(size=5)} for _ in range(2))
    policy = load_policy(policy_dir)
    policy.reset(metadata(key))
    mode = policy(first)
    plans = np.concatenate([mode[None, None], policy.sample_plans(first, 7)])
    log_prob = policy.log_prob_plans(first, plans)
    with torch.inference_mode():
        logits, means, stds = policy._distribution()
        expected = -gmm_nll(logits, means, stds, torch.as_tensor(plans.reshape(8, 7), dtype=means.dtype))
    np.testing.assert_allclose(log_prob, expected.double().numpy(), rtol=1e-6)
    assert log_prob.shape == (8,) and np.isfinite(log_prob).all()
    assert log_prob[0] > np.median(log_prob[1:])  # the mode's mean is likelier than a typical draw
    with_scoring = policy(second)
    policy.reset(metadata(key))
    policy(first)
    np.testing.assert_array_equal(policy(second), with_scoring)
