"""LIBERO's lifelong mechanisms as `train_policy` applies them (no simulator): ER's memory, EWC's penalty and
Fisher information, PackNet's masks and pruning, and resume with each."""

from __future__ import annotations

import copy
import os

import pytest
import torch
from test_policy_bc import SMALL, write_demos

from base_suites.runtime.errors import UserInputError
from elegant.policies.bc_artifact import read_artifact
from elegant.policies.bc_data import load_demos
from elegant.policies.bc_model import BCNet
from elegant.policies.bc_train import FineTuning, demo_batches, select_tasks, train_policy
from elegant.policies.continual import (
    ElasticAnchor,
    WeightMasks,
    consolidate,
    fisher_information,
    linear_weights,
    memory_digest,
    replay_memory,
)

TASK0, TASK1 = "libero_object/0", "libero_object/1"


@pytest.fixture(scope="module")
def demos(tmp_path_factory) -> str:
    return write_demos(tmp_path_factory.mktemp("continual") / "demos.hdf5", demos_per_task=4, steps=30)


@pytest.fixture(scope="module")
def first_task(demos, tmp_path_factory) -> str:
    """A policy trained on task 0 only, over the features of both tasks (a lifelong stage 0)."""
    from elegant.policies.bc_features import BCFeatures

    data = load_demos([demos])
    features = BCFeatures.fit(data, history=SMALL["config"].history, min_std=SMALL["config"].obs_min_std)
    out = str(tmp_path_factory.mktemp("stage0") / "policy")
    train_policy([demos], out, epochs=3, fine_tuning=FineTuning(tasks=[TASK0], features=features), **SMALL)
    return out


def weights(policy_dir: str) -> dict[str, torch.Tensor]:
    return read_artifact(policy_dir)[0].state_dict()


def test_replay_memory_holds_the_first_samples_of_earlier_tasks_only(demos):
    data = load_demos([demos])
    memory = replay_memory(data, [TASK0], 45)
    assert {e.task for e in memory.episodes} == {TASK0} and memory.num_samples == 45
    first = [e for e in data.episodes if e.task == TASK0]
    assert [len(e.actions) for e in memory.episodes] == [30, 15]  # the second demo is cut where the budget ends
    assert (memory.episodes[1].states == first[1].states[:15]).all()
    assert replay_memory(data, [TASK0], 10_000).num_samples == 4 * 30  # a budget above the data keeps all of it
    assert memory_digest(memory) != memory_digest(replay_memory(data, [TASK0], 44))
    with pytest.raises(UserInputError, match="er_memory must be a positive integer"):
        replay_memory(data, [TASK0], 0)


def test_replay_joins_every_batch_and_changes_what_is_learned(demos, first_task, tmp_path):
    data = load_demos([demos])
    plain, replayed = str(tmp_path / "plain"), str(tmp_path / "er")
    train_policy([demos], plain, epochs=2, fine_tuning=FineTuning(tasks=[TASK1], init_from=first_task), **SMALL)
    memory = replay_memory(data, [TASK0], 60)
    tune = FineTuning(tasks=[TASK1], init_from=first_task, replay=memory)
    result = train_policy([demos], replayed, epochs=2, fine_tuning=tune, **SMALL)
    assert result["num_samples"] == 4 * 30  # the epoch still goes over task 1's samples; the memory joins them
    a, b = weights(plain), weights(replayed)
    assert any(not torch.equal(a[k], b[k]) for k in a)
    # The replayed network fits task 0's memory better than the plain one does.
    features = read_artifact(first_task)[1]
    (x, actions), *_ = demo_batches(memory, features, chunk=1, batch_size=10_000, seed=0)
    nll = {name: read_artifact(d)[0].nll(x, actions).mean().item() for name, d in (("plain", plain), ("er", replayed))}
    assert nll["er"] < nll["plain"]


def test_ewc_penalty_is_zero_at_the_anchor_and_grows_with_distance():
    torch.manual_seed(0)
    net = BCNet(12, hidden=(8, 8), modes=2)
    fisher = {name: torch.rand_like(p) for name, p in net.named_parameters()}
    anchor = consolidate(None, fisher, net, weight=50.0, gamma=0.9)
    assert anchor.penalty(net).item() == 0.0
    penalties = []
    for step in (0.01, 0.02, 0.04):
        moved = BCNet(12, hidden=(8, 8), modes=2)
        moved.load_state_dict({k: v + step for k, v in net.state_dict().items()})
        penalties.append(anchor.penalty(moved).item())
    assert 0 < penalties[0] < penalties[1] < penalties[2]
    assert penalties[1] == pytest.approx(4 * penalties[0], rel=1e-4)  # quadratic in the distance
    expected = 50.0 * sum((fisher[k] * 0.01**2).sum().item() for k in fisher)
    assert penalties[0] == pytest.approx(expected, rel=1e-4)


def test_fisher_is_the_mean_squared_batch_gradient_and_decays_older_tasks(demos, first_task):
    net, features, _ = read_artifact(first_task)
    batches = demo_batches(select_tasks(load_demos([demos]), [TASK0]), features, chunk=1, batch_size=32, seed=0)
    fisher = fisher_information(net, batches, torch.device("cpu"))
    name = "trunk.0.weight"
    by_hand = torch.zeros_like(fisher[name])
    for x, actions in batches:
        net.zero_grad()
        (-net.nll(x, actions)).mean().backward()
        by_hand += net.trunk[0].weight.grad.square()
    assert torch.allclose(fisher[name], by_hand / len(batches))
    first = consolidate(None, fisher, net, weight=1.0, gamma=0.5)
    second = consolidate(first, fisher, net, weight=1.0, gamma=0.5)
    assert torch.allclose(second.fisher[name], 1.5 * fisher[name])


def test_ewc_training_stays_closer_to_the_anchor(demos, first_task, tmp_path):
    net, features, _ = read_artifact(first_task)
    batches = demo_batches(select_tasks(load_demos([demos]), [TASK0]), features, chunk=1, batch_size=32, seed=0)
    anchor = consolidate(None, fisher_information(net, batches, torch.device("cpu")), net, 5e4, 0.9)
    path = str(tmp_path / "anchor.pt")
    anchor.save(path)
    assert ElasticAnchor.load(path, 5e4).digest() == anchor.digest()
    distance = {}
    for name, tune in (
        ("plain", FineTuning(tasks=[TASK1], init_from=first_task)),
        ("ewc", FineTuning(tasks=[TASK1], init_from=first_task, anchor=ElasticAnchor.load(path, 5e4))),
    ):
        train_policy([demos], str(tmp_path / name), epochs=2, fine_tuning=tune, **SMALL)
        distance[name] = anchor.penalty(read_artifact(str(tmp_path / name))[0]).item()
    assert distance["ewc"] < distance["plain"]


def test_packnet_trains_only_owned_weights_and_never_biases(demos, first_task, tmp_path):
    net = read_artifact(first_task)[0]
    stage0 = WeightMasks({}, 0, claim_free=True).bind(net, "test")
    assert all((v == 1).all() for v in stage0.owner.values())  # task 0 claims every weight
    pruned = stage0.prune(net, 0.75)
    for name, owner in pruned.owner.items():
        freed = (owner == 0).float().mean().item()
        assert freed == pytest.approx(0.75, abs=0.02), name
        weight = dict(net.named_parameters())[name]
        assert (weight[owner == 0] == 0).all()
        assert weight[owner == 1].abs().min() >= weight[owner == 0].abs().max()
    path = str(tmp_path / "masks.pt")
    pruned.save(path)
    # Task 1 claims the freed weights and trains them only.
    masks = WeightMasks.load(path, 1, claim_free=True)
    before = {k: v.clone() for k, v in net.state_dict().items()}
    start = str(tmp_path / "pruned")
    from elegant.policies.bc_artifact import write_artifact

    features, artifact = read_artifact(first_task)[1:]
    os.makedirs(start)
    write_artifact(start, net, features, artifact["model"], artifact["training"])
    train_policy(
        [demos], str(tmp_path / "task1"), epochs=2, weight_decay=0.01,
        fine_tuning=FineTuning(tasks=[TASK1], init_from=start, masks=masks), **SMALL,
    )  # fmt: skip
    after = weights(str(tmp_path / "task1"))
    bound = masks.bind(net, "test")
    for name, value in after.items():
        if name in bound.owner:
            kept = bound.owner[name] == 1
            assert torch.equal(value[kept], before[name][kept]), name  # task 0's weights, even under weight decay
            assert not torch.equal(value[~kept], before[name][~kept]), name  # task 1's weights trained
        else:
            assert torch.equal(value, before[name]), name  # biases never train
    # Evaluating task 0 with its own weights recovers the network task 0 left behind.
    evaluated = read_artifact(str(tmp_path / "task1"))[0]
    bound.only_tasks_up_to(evaluated, 0)
    assert all(torch.equal(evaluated.state_dict()[k], before[k]) for k in before)


def test_packnet_masks_must_fit_the_network(first_task, tmp_path):
    masks = WeightMasks({"trunk.0.weight": torch.zeros(3, 3, dtype=torch.int16)}, 1)
    with pytest.raises(UserInputError, match="do not fit this network"):
        masks.bind(read_artifact(first_task)[0], "somewhere")
    (tmp_path / "bad.pt").write_bytes(b"not a torch file")
    with pytest.raises(UserInputError, match="unreadable PackNet masks"):
        WeightMasks.load(str(tmp_path / "bad.pt"), 1)


def test_packnet_prunes_every_weight_at_the_cut_off_value_and_only_the_tasks_own():
    """Per layer, the cut-off is the magnitude of the round(fraction * n)-th smallest of the task's n weights,
    and every weight of the task at that magnitude is freed too (LIBERO's `le`): ties at the cut-off free
    more than round(fraction * n). Weights of another task are never pruned, however small."""
    net = torch.nn.Sequential(torch.nn.Linear(4, 2), torch.nn.ReLU(), torch.nn.Linear(2, 3))
    with torch.no_grad():
        net[0].weight.copy_(torch.tensor([[0.1, -0.3, 0.3, 0.05], [-0.3, 0.5, -0.7, 0.9]]))
        net[2].weight.copy_(torch.tensor([[0.4, -0.2, 0.6], [0.8, -1.0, 0.3]]).T)
    biases = {name: p.detach().clone() for name, p in net.named_parameters() if name.endswith("bias")}
    # task 1 (owner 2) trains; the 0.05 of layer 0 belongs to task 0 (owner 1)
    owner = {
        "0.weight": torch.tensor([[2, 2, 2, 1], [2, 2, 2, 2]], dtype=torch.int16),
        "2.weight": torch.full((3, 2), 2, dtype=torch.int16),
    }
    pruned = WeightMasks(owner, 1).prune(net, 0.3)
    # layer 0: task 1's 7 weights, round(2.1) = 2: the cut-off is 0.3, held by three weights: 4 are freed
    assert pruned.owner["0.weight"].tolist() == [[0, 0, 0, 1], [0, 2, 2, 2]]
    # layer 2: 6 distinct magnitudes, round(1.8) = 2: exactly the two smallest (0.2 and 0.3) are freed
    assert pruned.owner["2.weight"].T.tolist() == [[2, 0, 2], [2, 2, 0]]
    torch.testing.assert_close(net[0].weight, torch.tensor([[0.0, 0.0, 0.0, 0.05], [0.0, 0.5, -0.7, 0.9]]))
    torch.testing.assert_close(net[2].weight.T, torch.tensor([[0.4, 0.0, 0.6], [0.8, -1.0, 0.0]]))
    assert all(torch.equal(p, biases[n]) for n, p in net.named_parameters() if n in biases)
    assert owner["0.weight"][0, 0] == 2  # the masks it was given are unchanged


def test_packnet_evaluates_each_earlier_task_with_the_weights_of_tasks_up_to_it(first_task, tmp_path):
    """After task 2, task j (j < 2) is evaluated with a network holding only the weights of tasks 0..j: the
    weights of the later tasks, and the free ones, are zero; the rest and every bias are the kept network's.
    Its output is then that of the kept network with tasks j+1.. removed, and differs from task to task."""
    from elegant.evaluation.lifelong_algos.packnet import PACKNET_MASKS_FILE, PackNet
    from elegant.evaluation.lifelong_run import LifelongRun
    from elegant.policies.bc_artifact import write_artifact

    net, features, artifact = read_artifact(first_task)
    owner = {}
    with torch.no_grad():  # weight i of each layer: free (0) or owned by task 0, 1 or 2 (1, 2, 3), in turn
        for name, weight in linear_weights(net).items():
            owner[name] = (torch.arange(weight.numel()) % 4).reshape(weight.shape).to(torch.int16)
            weight[owner[name] == 0] = 0.0  # a free weight is zero (pruned)
            weight.add_(torch.sign(weight) * (owner[name] == 3).float())  # task 2's weights: larger
    kept = str(tmp_path / "kept")
    os.makedirs(kept)
    write_artifact(kept, net, features, artifact["model"], artifact["training"])
    run = LifelongRun(tmp_path / "run", {}, [], None, features, lambda line: None, kept=[kept, kept, kept])
    masks_path = PackNet().masks_path(run, 2)
    assert masks_path.endswith(PACKNET_MASKS_FILE)
    os.makedirs(os.path.dirname(masks_path))
    WeightMasks(owner, 2).save(masks_path)

    plans = PackNet().earlier(run, 2)
    assert [(positions, str(run_dir)) for _, positions, run_dir in plans] == [
        ([j], str(tmp_path / "run" / "evals" / "after_task_2" / f"task_{j}")) for j in (0, 1)
    ]
    x = torch.randn(5, features.input_dim, generator=torch.Generator().manual_seed(0))
    outputs = []
    for j, (policy, _, _) in enumerate(plans):
        evaluated, _, facts = read_artifact(policy)
        assert facts["training"]["packnet_weights_of_tasks"] == list(range(j + 1))
        expected = {k: v.clone() for k, v in net.state_dict().items()}
        for name, own in owner.items():
            expected[name][(own == 0) | (own > j + 1)] = 0.0
            assert (evaluated.state_dict()[name][own > j + 1] == 0).all(), (j, name)
        assert all(torch.equal(evaluated.state_dict()[k], expected[k]) for k in expected), j
        by_hand = copy.deepcopy(net)
        by_hand.load_state_dict(expected)
        with torch.no_grad():
            output = torch.cat([t.flatten() for t in evaluated(x)])
            torch.testing.assert_close(output, torch.cat([t.flatten() for t in by_hand(x)]), rtol=0, atol=0)
        outputs.append(output)
    with torch.no_grad():
        full = torch.cat([t.flatten() for t in net(x)])
    assert not torch.allclose(outputs[0], outputs[1]) and not torch.allclose(outputs[1], full)


def test_resume_with_a_mechanism_gives_the_same_network_and_refuses_another(demos, first_task, tmp_path):
    data = load_demos([demos])
    tune = FineTuning(tasks=[TASK1], init_from=first_task, replay=replay_memory(data, [TASK0], 40))
    whole = str(tmp_path / "whole")
    train_policy([demos], whole, epochs=3, fine_tuning=tune, **SMALL)
    cut = str(tmp_path / "cut")

    def stop_after_one(info):
        if info["epoch"] == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train_policy([demos], cut, epochs=3, fine_tuning=tune, on_epoch_end=stop_after_one, **SMALL)
    train_policy([demos], cut, epochs=3, fine_tuning=tune, resume=True, **SMALL)
    assert open(os.path.join(cut, "model.pt"), "rb").read() == open(os.path.join(whole, "model.pt"), "rb").read()
    other = FineTuning(tasks=[TASK1], init_from=first_task, replay=replay_memory(data, [TASK0], 41))
    with pytest.raises(UserInputError, match="field 'continual.replay'"):
        train_policy([demos], cut, epochs=3, fine_tuning=other, resume=True, **SMALL)
