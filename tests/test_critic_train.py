"""Training the critic end to end on a tiny annotated file: artifact, metrics, resume after a real kill,
loading, run-time scoring, held-out evaluation, and the refusals users hit."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from dataclasses import replace

import numpy as np
import pytest
import torch
from test_critic_data import goal_geometry, task_layout, write_annotated

from base_suites.runtime.errors import UserInputError
from critics import auroc, evaluate_critic, load, train_critic
from critics.config import TrainConfig

# tiny networks, and the Cal-QL these tests were written against (the defaults are the recipe's outcome
# critic): per-step penalties backed up with the policy's action, at the annotation's gamma, one action per
# decision; each test sets what it examines on top
UNIT = TrainConfig(
    batch_size=32,
    hidden=[16, 16],
    n_actions=3,
    cql_weight=5.0,
    gamma=None,
    reward="step",
    chunk=1,
    backup="policy",
    weight_decay=0.0,
    mc_weight=0.0,
    value_loss="mse",
)
TINY = {"config": UNIT, "progress": False}


@pytest.fixture(scope="module")
def annotated(tmp_path_factory) -> str:
    return write_annotated(tmp_path_factory.mktemp("critic") / "train.hdf5")


@pytest.fixture(scope="module")
def trained(annotated, tmp_path_factory) -> tuple[str, dict]:
    out = str(tmp_path_factory.mktemp("critic") / "run")
    return out, train_critic([annotated], out, steps=6, log_every=2, checkpoint_every=3, **TINY)


def metadata(task_index: int, layout=None) -> dict:
    return {"suite": "libero_object", "task_index": task_index, "state_layout": layout or task_layout(task_index)}


def test_training_writes_artifact_metrics_and_summary(trained):
    out, summary = trained
    assert sorted(os.listdir(out)) == ["checkpoint.pt", "critic.json", "critic.pt", "metrics.csv"]
    assert summary["steps"] == 6 and summary["resumed_from"] is None and summary["demos"] == 6
    assert summary["tasks"] == ["libero_object/0", "libero_object/1"] and summary["gamma"] == 0.9
    assert np.isfinite(list(summary["final"].values())).all()
    with open(os.path.join(out, "metrics.csv")) as f:
        rows = list(csv.DictReader(f))
    assert [r["step"] for r in rows] == ["2", "4", "6"]
    assert {"loss_actor", "loss_qvalue", "loss_cql", "loss_alpha", "alpha"} <= set(rows[0])
    assert float(rows[-1]["loss_cql"]) == pytest.approx(summary["final"]["loss_cql"], rel=1e-5)
    critic = load(out)
    trained_params = torch.load(os.path.join(out, "checkpoint.pt"), weights_only=True)["loss"]
    for key, value in critic.network.state_dict().items():  # the artifact holds the final critics
        assert torch.equal(value, trained_params[f"qvalue_network_params.{key}"]), key
    config = critic.config
    assert set(config["versions"]) >= {"torch", "torchrl", "tensordict", "libero-elegant"}
    assert config["training"]["steps"] == 6 and config["encoder"]["layouts"]["libero_object/1"] == task_layout(1)


@pytest.mark.parametrize("task", [0, 1])
def test_loaded_critic_scores_raw_states_and_actions(trained, task):
    critic = load(trained[0]).bind(metadata(task))
    rng = np.random.default_rng(0)
    state = rng.normal(size=sum(s for _, s in task_layout(task)))
    actions = rng.uniform(-0.5, 0.5, size=(16, 7))
    q = critic.q(state, actions)
    assert q.shape == (16,) and q.dtype == np.float32
    batched = critic.q(np.stack([state, state * 2]), np.stack([actions, actions]))
    assert batched.shape == (2, 16) and np.allclose(batched[0], q, atol=1e-5)
    assert not np.allclose(batched[1], q)
    # the same numbers through the saved module: encode (pad + one-hot), normalise, map actions, min over twins
    norm, encoder = critic.normalization, critic.encoder
    obs = norm.observations(encoder.encode(state, f"libero_object/{task}"))
    with torch.no_grad():
        by_hand = critic.network(torch.from_numpy(obs)[None], torch.from_numpy(norm.actions(actions))[None]).amin(0)[0]
    assert np.allclose(q, by_hand.numpy(), atol=1e-5)
    # a state far outside the training range is clipped as in training, not extrapolated
    far = state * 1e4
    with torch.no_grad():
        far_by_hand = critic.network(
            torch.from_numpy(norm.observations(encoder.encode(far, f"libero_object/{task}")))[None],
            torch.from_numpy(norm.actions(actions))[None],
        ).amin(0)[0]
    assert np.allclose(critic.q(far, actions), far_by_hand.numpy(), atol=1e-5)
    assert np.allclose(critic.q(far, actions), critic.q(far * 10, actions), atol=1e-6)
    with pytest.raises(UserInputError, match="Critic.q expects state"):
        critic.q(np.append(state, 0.0), actions)


def test_bind_refuses_an_unknown_task_or_another_layout(trained):
    critic = load(trained[0])
    with pytest.raises(UserInputError, match="observation layout of env task libero_object/0 differs"):
        critic.bind(metadata(0, task_layout(1)))
    with pytest.raises(UserInputError, match="libero_object/7"):
        critic.bind(metadata(7))
    with pytest.raises(RuntimeError, match="bind"):
        critic.q(np.zeros(23), np.zeros((2, 7)))


def test_a_goal_relative_critic_scores_a_task_it_never_saw_exactly_as_its_network_does(annotated, trained, tmp_path):
    """Trained on libero_object tasks 0 and 1, it binds to libero_goal/5 (another layout, another name) whose
    goal it can read: `q`'s folded NumPy path equals the network on the encoded, normalised state."""
    from annotations import GoalFeatureEncoder

    out = str(tmp_path / "goal")
    config = replace(UNIT, encoding="goal-relative")
    summary = train_critic([annotated], out, steps=4, config=config, progress=False)
    assert np.isfinite(list(summary["final"].values())).all()
    critic = load(out)
    assert isinstance(critic.encoder, GoalFeatureEncoder) and critic.config["encoder"]["kind"] == "goal-relative"
    layout = task_layout(2)
    unseen = {"suite": "libero_goal", "task_index": 5, "state_layout": layout, "goal_geometry": goal_geometry(1)}
    critic.bind(unseen)
    rng = np.random.default_rng(1)
    state, actions = rng.normal(size=sum(s for _, s in layout)), rng.uniform(-0.5, 0.5, size=(4, 7))
    encoded = critic.encoder.encode(state, critic.encoder.check_env(unseen))
    by_network = critic.network(
        torch.from_numpy(critic.normalization.observations(encoded))[None],
        torch.from_numpy(critic.normalization.actions(actions))[None],
    ).amin(0)[0]
    np.testing.assert_allclose(critic.q(state, actions), by_network.numpy(), atol=1e-5)
    with pytest.raises(UserInputError, match="'libero_goal/5' is not among the tasks"):
        load(trained[0]).bind(unseen)  # the task one-hot knows only its tasks
    with pytest.raises(UserInputError, match="has no goal_geometry"):
        critic.bind({**unseen, "goal_geometry": None})


def test_tasks_keep_their_demos_only_and_an_absent_task_is_refused_before_anything_is_written(annotated, tmp_path):
    out = str(tmp_path / "one_task")
    summary = train_critic([annotated], out, steps=1, config=UNIT, tasks=("libero_object/1",), progress=False)
    assert summary["tasks"] == ["libero_object/1"] and summary["demos"] == 3
    with pytest.raises(UserInputError, match="tasks libero_object/7 have no demos"):
        train_critic([annotated], str(tmp_path / "none"), steps=1, config=UNIT, tasks=("libero_object/7",))
    assert not os.path.exists(tmp_path / "none")


def test_resume_after_a_kill_equals_an_uninterrupted_run(annotated, tmp_path):
    killed, straight = str(tmp_path / "killed"), str(tmp_path / "straight")
    child = textwrap.dedent(f"""
        import torch
        torch.set_num_threads(1)
        from critics import train_critic
        from critics.config import TrainConfig
        train_critic([{annotated!r}], {killed!r}, steps=10**6, log_every=1, checkpoint_every=4, **{TINY!r})
    """)
    proc = subprocess.Popen([sys.executable, "-c", child], stderr=subprocess.PIPE)
    ckpt = os.path.join(killed, "checkpoint.pt")
    deadline = time.monotonic() + 120
    while not os.path.exists(ckpt):
        assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
        assert time.monotonic() < deadline, "no checkpoint within 120 s"
        time.sleep(0.05)
    time.sleep(0.3)  # let it run past the checkpoint: the kill loses those steps
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    stopped_at = torch.load(ckpt, weights_only=True)["step"]
    total = stopped_at + 5

    resumed = train_critic([annotated], killed, steps=total, resume=True, log_every=1, checkpoint_every=4, **TINY)
    assert resumed["resumed_from"] == stopped_at
    train_critic([annotated], straight, steps=total, log_every=1, checkpoint_every=4, **TINY)

    a, b = (torch.load(os.path.join(d, "checkpoint.pt"), weights_only=True) for d in (killed, straight))
    assert a["step"] == b["step"] == total
    assert a["loss"].keys() == b["loss"].keys()
    for key in a["loss"]:
        assert torch.equal(a["loss"][key], b["loss"][key]), key
    assert torch.equal(a["torch_rng"], b["torch_rng"]) and torch.equal(a["sampler_rng"], b["sampler_rng"])
    with open(os.path.join(killed, "metrics.csv")) as fa, open(os.path.join(straight, "metrics.csv")) as fb:
        assert fa.read() == fb.read()


def test_evaluate_critic_counts_and_ranks(trained, annotated):
    report = evaluate_critic(trained[0], [annotated])
    assert report["n_elegant"] + report["n_violated"] == report["transitions"] == trained[1]["transitions"]
    assert report["n_elegant"] > 0 and report["n_violated"] > 0 and 0.0 <= report["auroc"] <= 1.0
    assert set(report["per_criterion"]) == {"sequence", "pose_accuracy", "alignment", "collision"}
    for c, r in report["per_criterion"].items():
        assert r["n_kept"] >= report["n_elegant"] and r["n_kept"] + r["n_violated"] == report["transitions"], c


def test_auroc_on_hand_made_scores():
    assert auroc([3.0, 2.0], [1.0, 2.0]) == pytest.approx(3.5 / 4)  # one tie counts half
    assert auroc([1.0], [2.0, 3.0]) == 0.0 and auroc([5.0, 6.0], [1.0]) == 1.0
    assert auroc([], [1.0]) is None


def test_refusals(trained, annotated, tmp_path):
    out, _ = trained
    with pytest.raises(UserInputError, match="no such critic directory"):
        load(tmp_path / "missing")
    broken = tmp_path / "broken"
    broken.mkdir()
    with pytest.raises(UserInputError, match="missing critic.json"):
        load(broken)
    for name in ("critic.json", "critic.pt"):
        with open(os.path.join(out, name), "rb") as f:
            (broken / name).write_bytes(f.read())
    (broken / "critic.pt").write_bytes(b"not a torch file")
    with pytest.raises(UserInputError, match=r"broken/critic.pt: corrupt"):
        load(broken)
    (broken / "critic.json").write_text("{ truncated")
    with pytest.raises(UserInputError, match=r"broken/critic.json: corrupt"):
        load(broken)

    unlabelled = write_annotated(tmp_path / "plain.hdf5", labelled=False)
    with pytest.raises(UserInputError, match="plain.hdf5: no ITC labels"):
        train_critic([unlabelled], str(tmp_path / "run"), steps=2, **TINY)
    with pytest.raises(UserInputError, match="plain.hdf5: no ITC labels"):
        evaluate_critic(out, [unlabelled])

    run = str(tmp_path / "again")
    train_critic([annotated], run, steps=2, **TINY)
    with pytest.raises(UserInputError, match="checkpoint.pt: exists; pass --resume"):
        train_critic([annotated], run, steps=4, **TINY)
    with pytest.raises(UserInputError, match="cannot resume with different seed"):
        train_critic([annotated], run, steps=4, resume=True, seed=1, **TINY)
    with open(os.path.join(run, "checkpoint.pt"), "r+b") as f:
        f.truncate(100)
    with pytest.raises(UserInputError, match="checkpoint.pt: unreadable checkpoint"):
        train_critic([annotated], run, steps=4, resume=True, **TINY)
    with pytest.raises(UserInputError, match="steps must be a positive integer"):
        train_critic([annotated], str(tmp_path / "zero"), steps=0, **TINY)


def test_the_in_sample_backup_reaches_the_loss_and_binds_a_resume(annotated, tmp_path):
    """backup="dataset" trains other critics than the default from the same seed, is recorded in the
    artifact's config, and a resume must keep it; an unknown backup is refused in one line."""
    runs = {b: str(tmp_path / b) for b in ("policy", "dataset")}
    for backup, run in runs.items():
        train_critic([annotated], run, steps=3, backup=backup, **TINY)
    weights = {b: torch.load(os.path.join(run, "critic.pt"), weights_only=True) for b, run in runs.items()}
    assert not all(torch.equal(weights["policy"][k], weights["dataset"][k]) for k in weights["policy"])
    with open(os.path.join(runs["dataset"], "critic.json")) as f:
        assert json.load(f)["training"]["backup"] == "dataset"
    with pytest.raises(UserInputError, match="cannot resume with different backup"):
        train_critic([annotated], runs["dataset"], steps=4, resume=True, **TINY)
    with pytest.raises(UserInputError, match="backup"):
        train_critic([annotated], str(tmp_path / "bad"), steps=1, backup="expectile", **TINY)


def test_bootstrap_members_load_as_an_ensemble_that_scores_with_each_of_them(annotated, tmp_path):
    """Members trained on bootstrap resamples record their resample and differ; comma-separated
    directories open as one `CriticEnsemble` whose `q` is the members' mean; a resume keeps the resample."""
    from critics import CriticEnsemble
    from elegant.evaluation.runner import open_critic

    members = [str(tmp_path / f"m{b}") for b in (1, 2)]
    for b, out in zip((1, 2), members):
        train_critic([annotated], out, steps=3, bootstrap=b, **TINY)
        assert load(out).config["training"]["bootstrap"] == b
    ensemble = open_critic(",".join(members))
    assert isinstance(ensemble, CriticEnsemble) and ensemble.chunk == 1
    ensemble.bind(metadata(1))
    rng = np.random.default_rng(0)
    state, actions = rng.normal(size=sum(s for _, s in task_layout(1))), rng.uniform(-0.5, 0.5, size=(5, 7))
    each = [load(m).bind(metadata(1)).q(state, actions) for m in members]
    assert np.allclose(ensemble.member_q(state, actions), each) and not np.allclose(*each)
    assert np.allclose(ensemble.q(state, actions), np.mean(each, axis=0))
    with pytest.raises(UserInputError, match="libero_object/7"):
        ensemble.bind(metadata(7))
    with pytest.raises(UserInputError, match="cannot resume with different bootstrap"):
        train_critic([annotated], members[0], steps=4, resume=True, bootstrap=2, **TINY)


def test_weight_decay_shrinks_the_critics_weights_only_and_binds_a_resume(annotated, tmp_path):
    runs = {wd: str(tmp_path / f"wd{wd}") for wd in (0.0, 0.5)}
    for wd, run in runs.items():
        train_critic([annotated], run, steps=20, weight_decay=wd, **{**TINY, "batch_size": 8})
    saved = {wd: torch.load(os.path.join(run, "critic.pt"), weights_only=True) for wd, run in runs.items()}
    norm = {wd: sum(float(v.norm()) for k, v in weights.items() if "weight" in k) for wd, weights in saved.items()}
    assert norm[0.5] < norm[0.0]
    with open(os.path.join(runs[0.5], "critic.json")) as f:
        assert json.load(f)["training"]["weight_decay"] == 0.5
    with pytest.raises(UserInputError, match="cannot resume with different weight_decay"):
        train_critic([annotated], runs[0.5], steps=21, resume=True, **{**TINY, "batch_size": 8})
    with pytest.raises(UserInputError, match="weight_decay must be >= 0"):
        train_critic([annotated], str(tmp_path / "bad"), steps=1, weight_decay=-1.0, **TINY)
    with pytest.raises(UserInputError, match="mc_weight must be >= 0"):
        train_critic([annotated], str(tmp_path / "bad"), steps=1, mc_weight=-1.0, **TINY)
    with pytest.raises(UserInputError, match="value_loss 'bce' needs returns in \\[0, 1\\], i.e. reward 'elegant'"):
        train_critic([annotated], str(tmp_path / "bad"), steps=1, value_loss="bce", reward="segment", **TINY)


def test_explored_fraction_fills_its_share_of_every_batch_with_explored_decisions(tmp_path):
    from critics.config import TrainConfig
    from critics.data import load_transitions
    from critics.train import _Run

    path = write_annotated(tmp_path / "x.hdf5", n_demos=4, explored_at={0: [2, 5], 1: [0], 3: [7]})
    data = load_transitions([path], TrainConfig(gamma=None, reward="step", chunk=1, value_loss="mse"))
    explored = {tuple(row.tolist()) for row in data.transitions["observation"][data.explored]}
    run = _Run(TrainConfig(paths=[path], steps=1, batch_size=8, hidden=[16], n_actions=2, explored_fraction=0.25), data)
    batches = []
    forward = run.loss.forward
    run.loss.forward = lambda td: batches.append(td) or forward(td)
    for _ in range(5):
        run.step()
    for batch in batches:
        rows = [tuple(o.tolist()) in explored for o in batch["observation"]]
        assert len(rows) == 8 and all(rows[6:])  # 8 * 0.25 explored rows after the uniform ones
    summary = train_critic([path], str(tmp_path / "run"), steps=3, explored_fraction=0.25, **{**TINY, "batch_size": 8})
    with open(os.path.join(summary["out"], "critic.json")) as f:
        assert json.load(f)["training"]["explored_fraction"] == 0.25
    with pytest.raises(UserInputError, match="cannot resume with different explored_fraction"):
        train_critic([path], summary["out"], steps=4, resume=True, **{**TINY, "batch_size": 8})


def test_explored_fraction_refusals(annotated, tmp_path):
    with pytest.raises(UserInputError, match="no demo in .* has explored_steps"):
        train_critic([annotated], str(tmp_path / "none"), steps=1, explored_fraction=0.5, **TINY)
    for fraction in (1.0, -0.1, 0.001):  # all explored, negative, or no explored row in a batch
        with pytest.raises(UserInputError, match="explored_fraction must lie in \\[0, 1\\)"):
            train_critic([annotated], str(tmp_path / "bad"), steps=1, explored_fraction=fraction, **TINY)


def test_an_elegant_success_critic_with_the_bce_value_loss_trains_and_records_it(annotated, tmp_path):
    summary = train_critic(
        [annotated], str(tmp_path / "bce"), steps=4, reward="elegant", value_loss="bce", gamma=0.99, **TINY
    )
    assert all(np.isfinite(v) for v in summary["final"].values())
    with open(os.path.join(summary["out"], "critic.json")) as f:
        training = json.load(f)["training"]
    assert (training["reward"], training["value_loss"]) == ("elegant", "bce")


def test_a_chunk_critic_scores_flattened_chunks_normalised_step_by_step(annotated, tmp_path):
    from critics import action_chunks

    out = str(tmp_path / "chunked")
    summary = train_critic([annotated], out, steps=4, chunk=3, **TINY)
    critic = load(out).bind(metadata(1))
    assert critic.chunk == 3 and critic.network.action_dim == 21 and critic.config["chunk"] == 3
    rng = np.random.default_rng(0)
    state = rng.normal(size=sum(s for _, s in task_layout(1)))
    chunks = rng.uniform(-0.5, 0.5, size=(5, 21))
    q = critic.q(state, chunks)
    obs = critic.normalization.observations(critic.encoder.encode(state, "libero_object/1"))
    scaled = np.stack([critic.normalization.actions(c.reshape(3, 7)).reshape(-1) for c in chunks])
    with torch.no_grad():
        by_hand = critic.network(torch.from_numpy(obs)[None], torch.from_numpy(scaled)[None]).amin(0)[0]
    assert q.shape == (5,) and np.allclose(q, by_hand.numpy(), atol=1e-5) and summary["steps"] == 4
    with pytest.raises(UserInputError, match=r"actions \(N, 21\).*chunks of 3 actions"):
        critic.q(state, chunks[:, :7])
    assert action_chunks(np.arange(6).reshape(3, 2), 2).tolist() == [[0, 1, 2, 3], [2, 3, 4, 5], [4, 5, 4, 5]]
    result = evaluate_critic(out, [annotated])  # held-out scoring builds each step's chunk from the demo
    assert result["transitions"] == summary["transitions"] and 0.0 <= result["auroc"] <= 1.0


def test_divergence_is_refused_naming_the_step_and_what_went_non_finite():
    import math

    import torch

    from critics.divergence import refuse_divergence

    net = torch.nn.Linear(2, 2)
    refuse_divergence("train-critic", "step 3", {"loss_qvalue": 1.0}, net)  # finite: nothing happens
    with pytest.raises(UserInputError, match=r"train-critic: training diverged at step 3 \(non-finite loss_cql\)"):
        refuse_divergence("train-critic", "step 3", {"loss_qvalue": 1.0, "loss_cql": math.nan}, net)
    with torch.no_grad():
        net.weight[0, 0] = math.inf
    with pytest.raises(UserInputError, match=r"at step 4 \(non-finite weights\)"):
        refuse_divergence("train-critic", "step 4", {"loss_qvalue": 1.0}, net)
