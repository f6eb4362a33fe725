"""The critic's data path: annotated HDF5 -> normalised transitions -> seeded replay buffer.

`write_annotated` (random arrays in the documented layout) is also used by tests/test_critic_train.py.
"""

from __future__ import annotations

from dataclasses import replace

import h5py
import numpy as np
import pytest
import torch

from annotations import CRITERIA, SEGMENT_LENGTH, Demo, DemoWriter
from base_suites.runtime.errors import UserInputError
from critics import Normalization, TrainConfig, load_transitions, make_replay_buffer
from critics.data import NO_FLOOR
from critics.normalization import MAX_ABS_Z, MIN_STD

# The data settings these tests were written against: the step penalty, one action per transition and the
# annotation's gamma (the recipe's are the elegant reward, chunks of 8 and 0.995); each test sets what it
# examines on top.
STEP = TrainConfig(gamma=None, reward="step", chunk=1, value_loss="mse")


def load(paths, **settings):
    return load_transitions(paths, replace(STEP, **settings))


ROBOT = [["robot0_eef_pos", 3], ["robot0_eef_quat", 4], ["robot0_gripper_qpos", 2], ["robot0_joint_pos", 7]]


def task_layout(task_index: int) -> list[list]:
    """Task i has i + 1 objects, so the tasks' state widths differ (padding is exercised)."""
    return ROBOT + [[f"obj{k}/{part}", size] for k in range(task_index + 1) for part, size in (("pos", 3), ("quat", 4))]


def goal_geometry(task_index: int) -> dict:
    """A recorded goal for the tasks of `task_layout`: task 0 puts obj0 on a table region; task i > 0 puts
    obj1 into a region riding on obj0 (a basket's inside)."""
    if task_index == 0:
        goal, region = [["on", "obj0", "table_region"]], {"frame": "world", "parent": None, "position": [0.1, 0.2, 0.9]}
    else:
        goal, region = (
            [["in", "obj1", "obj0_contain_region"]],
            {"frame": "object", "parent": "obj0", "position": [0, 0, 0.05]},
        )
    region.update(rotation=[1, 0, 0, 0, 1, 0, 0, 0, 1], half_size=[0.05, 0.05, 0.02])
    return {
        "version": 1,
        "goal": goal,
        "robot_base": [-0.6, 0.0, 0.9],
        "table_height": 0.9,
        "regions": {goal[0][2]: region},
        "articulations": {},
    }


def discounted_returns(rewards: np.ndarray, gamma: float) -> np.ndarray:
    out, acc = np.zeros(len(rewards)), 0.0
    for t in reversed(range(len(rewards))):
        acc = rewards[t] + gamma * acc
        out[t] = acc
    return out


def write_annotated(
    path,
    *,
    n_demos: int = 6,
    seed: int = 0,
    gamma: float = 0.9,
    labelled: bool = True,
    lengths: tuple[int, int] = (30, 60),
    corrupt_return: bool = False,
    violation_rate: float = 0.01,
    violate_at: dict[int, int] | None = None,
    explored_at: dict[int, list] | None = None,
) -> str:
    """An annotated file of two libero_object tasks with random states, actions and ITC labels.

    Demo i belongs to task i % 2 and succeeds when i % 3 != 2; actions use [-0.5, 0.5] in every dimension.
    Each step violates each criterion with `violation_rate`; `violate_at` {demo: step} adds a collision there;
    `explored_at` {demo: steps} records those steps as explored decisions, as `elegant rollouts` does.
    """
    rng = np.random.default_rng(seed)
    attrs = (
        {"annotation": {"schema_version": 1, "gamma": gamma, "segment_length": SEGMENT_LENGTH, "itc_params": {}}}
        if labelled
        else {}
    )
    writer = DemoWriter(str(path), attrs)
    for i in range(n_demos):
        task = i % 2
        layout = task_layout(task)
        t = int(rng.integers(*lengths))
        states = rng.normal(size=(t + 1, sum(s for _, s in layout))).astype(np.float32)
        success = i % 3 != 2
        rewards = np.zeros(t, np.float32)
        rewards[-1] = float(success)
        dones = np.zeros(t, np.uint8)
        dones[-1] = 1
        demo = Demo(
            name="",
            actions=rng.uniform(-0.5, 0.5, size=(t, 7)),
            states=rng.normal(size=(t, 4)),
            obs=states[:-1],
            next_obs=states[1:],
            rewards=rewards,
            dones=dones,
            attrs={
                "suite": "libero_object",
                "task_index": task,
                "task_name": f"task {task}",
                "success": success,
                "goal_geometry": goal_geometry(task),
                **({"explored_steps": explored_at[i]} if i in (explored_at or {}) else {}),
            },
        )
        if labelled:
            itc = {c: rng.random(t) >= violation_rate for c in CRITERIA}
            if i in (violate_at or {}):
                itc["collision"][violate_at[i]] = False
            n_seg = -(-t // SEGMENT_LENGTH)
            demo.itc = itc
            demo.itc_segments = {
                c: np.array([itc[c][k * SEGMENT_LENGTH : (k + 1) * SEGMENT_LENGTH].all() for k in range(n_seg)])
                for c in CRITERIA
            }
            demo.elegance_reward = np.logical_and.reduce([itc[c] for c in CRITERIA]).astype(np.float32)
            demo.mc_return = discounted_returns(demo.elegance_reward, gamma).astype(np.float32) + (
                0.5 if corrupt_return else 0.0
            )
        writer.append(demo, layout)
    return writer.finish()


@pytest.fixture()
def annotated(tmp_path) -> str:
    return write_annotated(tmp_path / "train.hdf5")


def read_raw(path: str) -> list[dict]:
    with h5py.File(path, "r") as f:
        names = sorted((n for n in f["data"] if n.startswith("demo_")), key=lambda n: int(n.split("_")[1]))
        return [
            {k: f["data"][n][k][()] for k in ("actions", "obs/state", "next_obs/state", "elegance_reward", "rewards")}
            | {"task": int(f["data"][n].attrs["task_index"])}
            for n in names
        ]


def test_transitions_follow_the_documented_layout(annotated):
    data = load([annotated])
    td = data.transitions
    raw = read_raw(annotated)
    total = sum(len(d["actions"]) for d in raw)
    assert td.batch_size == torch.Size([total])
    assert data.encoder.tasks == ["libero_object/0", "libero_object/1"]
    width = data.encoder.state_dim
    assert width == 16 + 14 and data.obs_dim == width + 2 and data.action_dim == 7
    for key in ("mc_return", ("next", "reward"), ("next", "done"), ("next", "terminated"), ("next", "truncated")):
        assert td.get(key).shape == (total, 1), key
    assert td["observation"].dtype == torch.float32 and td["next", "done"].dtype == torch.bool

    # normalised state part, untouched one-hot
    obs = td["observation"].numpy()
    assert np.allclose(obs[:, :width].mean(0), 0, atol=1e-4) and np.allclose(obs[:, :width].std(0), 1, atol=1e-3)
    tasks = np.concatenate([[d["task"]] * len(d["actions"]) for d in raw])
    assert np.array_equal(obs[:, width:], np.eye(2, dtype=np.float32)[tasks])
    # states and next states stay paired, and normalisation inverts to the raw numbers
    raw_obs = data.normalization.obs_mean + obs[:, :width] * data.normalization.obs_std
    d0 = raw[0]["obs/state"]
    assert np.allclose(raw_obs[: len(d0), : d0.shape[1]], d0, atol=1e-5)
    assert np.allclose(raw_obs[: len(d0), d0.shape[1] :], 0, atol=1e-5)  # padding of the narrower task
    assert np.allclose(td["next", "observation"][: len(d0) - 1].numpy(), obs[1 : len(d0)], atol=1e-6)

    # the dataset's next action: the demo's following step's, its own at the demo's last step
    ends = np.cumsum([len(d["actions"]) for d in raw]) - 1
    following = np.arange(total) + 1
    following[ends] = ends
    np.testing.assert_array_equal(td["next", "action"].numpy(), td["action"].numpy()[following])

    # actions mapped onto [-1, 1] by the dataset's bounds
    actions = td["action"].numpy()
    assert np.allclose(actions.min(0), -1) and np.allclose(actions.max(0), 1)
    raw_actions = np.concatenate([d["actions"] for d in raw])
    assert np.allclose(data.normalization.action_low, raw_actions.min(0)) and np.allclose(
        data.normalization.action_high, raw_actions.max(0)
    )


def test_episode_ends_and_returns(annotated):
    data = load([annotated])
    td = data.transitions
    raw = read_raw(annotated)
    ends = np.cumsum([len(d["actions"]) for d in raw]) - 1
    done = td["next", "done"].squeeze(-1).numpy()
    assert np.array_equal(np.flatnonzero(done), ends)
    success = np.array([d["rewards"][-1] > 0 for d in raw])
    assert np.array_equal(np.flatnonzero(td["next", "terminated"].squeeze(-1).numpy()), ends[success])
    assert np.array_equal(np.flatnonzero(td["next", "truncated"].squeeze(-1).numpy()), ends[~success])
    # Training reward: the violation penalty r - 1; its returns floor Cal-QL only for successful demos.
    penalty = [d["elegance_reward"] - 1.0 for d in raw]
    assert np.allclose(td["next", "reward"].squeeze(-1).numpy(), np.concatenate(penalty))
    expected = np.concatenate(
        [discounted_returns(p, 0.9) if ok else np.full(len(p), NO_FLOOR) for p, ok in zip(penalty, success)]
    )
    assert np.allclose(td["mc_return"].squeeze(-1).numpy(), expected, atol=1e-5)
    last_penalty = np.array([p[-1] for p in penalty])
    assert np.allclose(td["mc_return"].squeeze(-1).numpy()[ends[success]], last_penalty[success])
    assert data.gamma == 0.9


def test_critic_discount_can_differ_from_the_annotations(annotated):
    data = load([annotated], gamma=0.5)
    raw = read_raw(annotated)
    success = np.array([d["rewards"][-1] > 0 for d in raw])
    expected = np.concatenate(
        [
            discounted_returns(d["elegance_reward"] - 1.0, 0.5) if ok else np.full(len(d["actions"]), NO_FLOOR)
            for d, ok in zip(raw, success)
        ]
    )
    assert data.gamma == 0.5
    assert np.allclose(data.transitions["mc_return"].squeeze(-1).numpy(), expected, atol=1e-5)
    with pytest.raises(UserInputError, match="gamma must lie in"):
        load([annotated], gamma=1.0)


def test_segment_reward_penalises_every_step_of_a_violating_window(annotated):
    """reward="segment": a one-step violation costs its whole 25-frame window (human labels live there too)."""
    data = load([annotated], reward="segment")
    with h5py.File(annotated, "r") as f:
        demos = [f["data"][f"demo_{i}"] for i in range(6)]
        windows = [np.logical_and.reduce([d["itc_segments"][c][()] for c in CRITERIA]) for d in demos]
        lengths = [len(d["actions"]) for d in demos]
        success = [d["rewards"][-1] > 0 for d in demos]
    penalty = [w[np.arange(t) // SEGMENT_LENGTH].astype(np.float32) - 1.0 for w, t in zip(windows, lengths)]
    reward = data.transitions["next", "reward"].squeeze(-1).numpy()
    assert np.array_equal(reward, np.concatenate(penalty))
    # the per-step form penalises fewer steps: only those that violate (random labels break ~4% of steps)
    steps = load([annotated]).transitions["next", "reward"].squeeze(-1).numpy()
    assert (steps < 0).sum() < (reward < 0).sum() and np.all(reward[steps < 0] < 0)
    expected = np.concatenate(
        [discounted_returns(p, 0.9) if ok else np.full(len(p), NO_FLOOR) for p, ok in zip(penalty, success)]
    )
    assert np.allclose(data.transitions["mc_return"].squeeze(-1).numpy(), expected, atol=1e-5)
    with pytest.raises(UserInputError, match="unknown reward 'window'"):
        load([annotated], reward="window")


def test_elegant_reward_pays_an_elegant_success_and_ends_at_the_first_violating_window(tmp_path):
    """reward="elegant": Q is the discounted chance of an elegant success, the binary outcome ESR counts."""
    path = write_annotated(tmp_path / "e.hdf5", n_demos=3, lengths=(60, 61), violation_rate=0.0, violate_at={1: 40})
    td = load([path], gamma=0.9, reward="elegant").transitions
    reward, ret = td["next", "reward"].squeeze(-1).numpy(), td["mc_return"].squeeze(-1).numpy()
    done, terminated = td["next", "done"].squeeze(-1).numpy(), td["next", "terminated"].squeeze(-1).numpy()
    elegant, violated, failed = np.split(np.arange(180), [60, 120])  # demo 0 elegant, 1 collides at 40, 2 fails cleanly
    assert np.flatnonzero(reward).tolist() == [59] and reward[59] == 1.0
    np.testing.assert_allclose(ret[elegant], 0.9 ** np.arange(59, -1, -1), rtol=1e-6)
    assert not ret[violated].any() and not ret[failed].any()  # every return exact: Cal-QL floors with all
    # the collision at step 40 breaks window 25-49: from its start no elegant success is possible
    assert np.flatnonzero(done).tolist() == [59, *range(60 + 25, 120), 179] and np.array_equal(done, terminated)
    assert not td["next", "truncated"].any()
    chunked = load([path], gamma=0.9, reward="elegant", chunk=8).transitions
    assert (
        chunked["next", "terminated"][60 + 20].item() and chunked["steps_to_next_obs"][60 + 20].item() == 6
    )  # ends with step 25
    assert not chunked["next", "terminated"][60 + 8].item() and chunked["next", "reward"][60 + 8].item() == 0.0
    assert chunked["next", "reward"][52].item() == pytest.approx(0.9**7)  # the chunk that ends the elegant success


def test_explored_decisions_are_marked_on_their_rows(tmp_path):
    path = write_annotated(tmp_path / "x.hdf5", n_demos=3, lengths=(30, 31), explored_at={0: [3, 10], 2: [0]})
    for chunk in (1, 8):  # chunk transitions keep one row per step
        data = load([path], chunk=chunk)
        assert data.explored.dtype == torch.bool and len(data.explored) == len(data.transitions)
        assert torch.nonzero(data.explored).flatten().tolist() == [3, 10, 60]
    bad = write_annotated(tmp_path / "bad.hdf5", n_demos=2, lengths=(30, 31), explored_at={1: [30]})
    with pytest.raises(
        UserInputError, match=r"data/demo_1: attr explored_steps must list step indices in \[0, 30\), got \[30\]"
    ):
        load([bad])


def test_the_data_fingerprint_follows_the_explored_decisions(tmp_path):
    """A resume must notice when the explored rows changed, though every transition stayed the same."""

    def fingerprint(name, explored_at):
        return load(
            [write_annotated(tmp_path / name, n_demos=3, lengths=(30, 31), explored_at=explored_at)]
        ).fingerprint()

    plain = fingerprint("plain.hdf5", None)
    assert fingerprint("empty.hdf5", {0: []}) == plain  # no explored row: digested as before the mask existed
    first = fingerprint("a.hdf5", {0: [3]})
    assert first != plain and first != fingerprint("b.hdf5", {0: [4]}) and first == fingerprint("c.hdf5", {0: [3]})


def test_a_bootstrap_resample_draws_whole_episodes_with_replacement_by_its_seed(tmp_path):
    """An ensemble member trains on as many episodes as there are, drawn with replacement: whole episodes
    (each one's length and actions intact), the same draw for the same seed, another for another."""
    path = write_annotated(tmp_path / "b.hdf5", n_demos=8)

    def episodes(data):
        """Each episode's raw actions, in the order the transitions hold them."""
        td, norm = data.transitions, data.normalization
        ends = np.flatnonzero(td["next", "done"].squeeze(-1).numpy()) + 1
        raw = td["action"].numpy() * norm.action_half_range + norm.action_center
        return [np.round(a, 4).tobytes() for a in np.split(raw, ends[:-1])]

    whole = episodes(load([path]))
    drawn = episodes(load([path], bootstrap=3))
    assert len(drawn) == len(whole) == 8
    assert set(drawn) <= set(whole) and len(set(drawn)) < len(set(whole))  # some episodes twice, some left out
    assert load([path], bootstrap=3).fingerprint() == load([path], bootstrap=3).fingerprint()
    assert episodes(load([path], bootstrap=4)) != drawn


def test_refuses_unlabelled_and_miscalibrated_files(tmp_path):
    plain = write_annotated(tmp_path / "plain.hdf5", labelled=False)
    with pytest.raises(UserInputError, match="plain.hdf5: no ITC labels"):
        load([plain])
    wrong = write_annotated(tmp_path / "wrong.hdf5", corrupt_return=True)
    with pytest.raises(UserInputError, match=r"wrong.hdf5: data/demo_0/mc_return differs"):
        load([wrong])
    other_gamma = write_annotated(tmp_path / "other.hdf5", gamma=0.5)
    with pytest.raises(UserInputError, match="gamma"):
        load([write_annotated(tmp_path / "a.hdf5"), other_gamma])


def test_replay_buffer_sampling_is_seeded(annotated):
    data = load([annotated])

    def draws(seed: int) -> list[torch.Tensor]:
        buffer = make_replay_buffer(data.transitions, 16, torch.Generator().manual_seed(seed))
        return [buffer.sample()["action"] for _ in range(3)]

    a, b, c = draws(0), draws(0), draws(1)
    assert all(torch.equal(x, y) for x, y in zip(a, b))
    assert not all(torch.equal(x, y) for x, y in zip(a, c))
    assert a[0].shape == (16, 7)


def test_normalization_round_trips_and_guards_constant_dimensions():
    obs = np.stack([np.arange(6.0), np.full(6, 3.0), np.ones(6)], axis=1)  # last column: a one-hot (not normalised)
    actions = np.stack([np.linspace(-0.5, 0.5, 6), np.zeros(6)], axis=1)
    norm = Normalization.fit(obs, actions, state_dim=2)
    assert norm.obs_std[1] == pytest.approx(MIN_STD)  # constant: only shifted in training
    assert np.allclose(norm.observations(obs)[:, 1], 0) and np.array_equal(norm.observations(obs)[:, 2], obs[:, 2])
    mapped = norm.actions(actions)
    assert np.allclose(mapped[:, 0], np.linspace(-1, 1, 6)) and np.allclose(mapped[:, 1], 0)
    assert np.allclose(norm.actions([[2.0, 0.5]]), [[1.0, 1.0]])  # outside the data's bounds: clipped
    again = Normalization.from_dict(norm.to_dict())
    assert all(
        np.array_equal(getattr(again, k), getattr(norm, k))
        for k in ("obs_mean", "obs_std", "action_low", "action_high")
    )


def test_a_dimension_that_rarely_moves_does_not_blow_up_its_outliers():
    """An object's orientation that changes in one transition of 10,000 (it was knocked over) must not
    reach the network as an input of ~100; an ordinary dimension keeps its standard deviation."""
    rng = np.random.default_rng(0)
    ordinary = rng.normal(0.3, 0.05, size=10_000)
    rare = np.full(10_000, 0.7)
    rare[17] = 0.0
    jitter = np.full(10_000, 0.15)
    jitter[5000:] += 3e-5  # a box nudged by 0.03 mm
    obs = np.stack([ordinary, rare, jitter], axis=1)
    norm = Normalization.fit(obs, np.zeros((10_000, 1)), state_dim=3)
    z = norm.observations(obs)
    assert norm.obs_std[0] == pytest.approx(ordinary.std(), rel=1e-5)
    assert np.abs(z).max() <= MAX_ABS_Z + 1e-4 and abs(z[17, 1]) > 9  # the outlier still stands out
    assert np.abs(z[:, 2]).max() < 0.05  # jitter stays jitter


def test_chunk_transitions_sum_the_chunks_penalties_and_bootstrap_after_the_chunk(annotated):
    """chunk=4: step t's action is a_t..a_t+3 (last repeated past the end), its reward the discounted sum
    of those steps' penalties, its next state the one after the chunk, its next action the chunk that
    starts there, its end flags the chunk's last step's."""
    per_step, chunked = load([annotated], gamma=0.5), load([annotated], gamma=0.5, chunk=4)
    one, four = per_step.transitions, chunked.transitions
    assert chunked.chunk == 4 and four.batch_size == one.batch_size and four["action"].shape[-1] == 28
    lengths = [len(d["actions"]) for d in read_raw(annotated)]
    start = 0
    for length in lengths:
        rows = np.arange(start, start + length)
        end = start + length - 1
        for t in (start, end - 5, end - 2, end):
            ahead = np.minimum(t + np.arange(4), end)
            np.testing.assert_array_equal(four["action"][t].numpy(), one["action"][ahead].numpy().reshape(-1))
            steps = min(4, end - t + 1)
            reward = sum(0.5**i * float(one["next", "reward"][t + i]) for i in range(steps))
            assert float(four["next", "reward"][t]) == pytest.approx(reward)
            assert int(four["steps_to_next_obs"][t]) == steps
            np.testing.assert_array_equal(
                four["next", "observation"][t].numpy(), one["next", "observation"][t + steps - 1].numpy()
            )
            np.testing.assert_array_equal(
                four["next", "action"][t].numpy(), four["action"][min(t + steps, end)].numpy()
            )
            for flag in ("done", "terminated", "truncated"):
                assert bool(four["next", flag][t]) == bool(one["next", flag][t + steps - 1])
        np.testing.assert_array_equal(four["mc_return"][rows].numpy(), one["mc_return"][rows].numpy())
        start += length
    with pytest.raises(UserInputError, match="chunk must be a positive integer"):
        load([annotated], chunk=0)
