"""Policy rollouts recorded as a dataset (`elegant rollouts`), on the real simulator: the episodes start
where evaluation episodes would, exploration is recorded and seeded, an interrupted file resumes to the
same content, and `annotate_file` labels the result like any demo file."""

import numpy as np
import pytest
from conftest import interrupted_at_second_episode

from annotations import CRITERIA, DemoFile, annotate_file
from base_suites import UserInputError, make_env
from base_suites.suites import get_task
from elegant.evaluation.rollouts import branch_points_reached, branch_step, collect_rollouts
from elegant.evaluation.runner import episode_start
from itc import ITCMonitor

pytestmark = pytest.mark.sim
SUITE, TASK, STEPS, INITS = "libero_object", 0, 12, [3, 7, 9]


class Lower:
    """Lowers the open hand; `sample` offers candidates drifting in x by k / 20 (k = 0 is the action)."""

    def __call__(self, obs):
        return np.array([0.0, 0.0, -0.5, 0.0, 0.0, 0.0, -1.0])

    def sample(self, obs, n):
        out = np.repeat(self(obs)[None], n, axis=0)
        out[:, 0] = np.arange(n) / 20.0
        return out


def collect_into(path, episodes=2, **kw):
    return collect_rollouts(
        SUITE,
        [TASK],
        Lower(),
        str(path),
        episodes=episodes,
        explore=0.5,
        trust_radius=0.3,
        init_states=INITS,
        seed=4,
        max_steps=STEPS,
        progress=False,
        **kw,
    )


def test_rollouts_start_like_eval_record_exploration_and_resume(tmp_path, monkeypatch):
    summary = collect_into(tmp_path / "full.hdf5")
    assert summary["episodes"] == 2 and 0 < summary["explored_per_episode"] < STEPS
    with DemoFile(summary["out"]) as f:
        demos = list(f)
    for i, demo in enumerate(demos):
        init, reset_seed = episode_start(4, SUITE, TASK, i, 50, INITS)
        assert (demo.attrs["init_state_index"], demo.attrs["reset_seed"]) == (init, reset_seed) and init in INITS
        assert demo.attrs["goal_geometry"]["goal"] == [list(p) for p in get_task(SUITE, TASK).goal]
        explored = demo.attrs["explored_steps"]
        assert demo.attrs["rollout"]["mode"] == "random" and demo.attrs["rollout"]["random_rate"] == 0.5
        moved = [t for t in range(demo.num_samples) if demo.actions[t][0] != 0.0]
        assert moved == explored  # exactly the explored steps deviate, by an eligible candidate
        assert all(0.0 < demo.actions[t][0] <= 0.3 for t in explored)

    interrupted_at_second_episode(monkeypatch, lambda: collect_into(tmp_path / "cut.hdf5"))
    with pytest.raises(UserInputError, match="cannot resume with different rollout"):
        collect_rollouts(
            SUITE,
            [TASK],
            Lower(),
            str(tmp_path / "cut.hdf5"),
            episodes=2,
            explore=0.3,
            trust_radius=0.3,
            init_states=INITS,
            seed=4,
            max_steps=STEPS,
            progress=False,
            resume=True,
        )
    resumed = collect_into(tmp_path / "cut.hdf5", resume=True)
    parallel = collect_into(tmp_path / "parallel.hdf5", workers=2)  # each episode on its own worker process
    for other in (resumed, parallel):
        with DemoFile(summary["out"]) as a, DemoFile(other["out"]) as b:
            for da, db in zip(a, b, strict=True):
                assert np.array_equal(da.actions, db.actions) and np.array_equal(da.obs, db.obs)
                assert da.attrs["explored_steps"] == db.attrs["explored_steps"]

    annotated = annotate_file(summary["out"], str(tmp_path / "annotated.hdf5"), progress=False)
    assert annotated["demos"] == 2
    with DemoFile(str(tmp_path / "annotated.hdf5"), require_labels=True) as f:
        labelled = list(f)
    env = make_env(SUITE, TASK, seed=4, max_steps=STEPS)
    monitor = ITCMonitor(env)
    for demo in labelled:
        # replay gate: the recorded actions, run live under the monitor, give the labels the annotation
        # computed from the stored states, at every step (the last transition included: it is replayed
        # from the recorded final state, not re-simulated without the controller's internal state)
        env.reset(seed=int(demo.attrs["reset_seed"]), options={"init_state": int(demo.attrs["init_state_index"])})
        monitor.reset()
        for action in demo.actions:
            _, _, _, _, info = env.step(action)
            monitor.step(action)
        np.testing.assert_array_equal(env.get_sim_state(), demo.final_state)
        live = monitor.verdict(bool(info["success"]))
        for c in CRITERIA:
            np.testing.assert_array_equal(demo.itc[c], live.steps[c], err_msg=c)
        assert demo.attrs["success"] == live.success and demo.mc_return.shape == (demo.num_samples,)
    env.close()


def test_explore_at_branches_each_start_once_per_point_from_a_shared_prefix(tmp_path, capsys):
    # 3 starts, points [2, 5]: episodes 0-2 branch at step 2, 3-5 at step 5, each start once per point
    summary = collect_rollouts(
        SUITE,
        [TASK],
        Lower(),
        str(tmp_path / "branches.hdf5"),
        episodes=6,
        explore_at=[2, 5],
        trust_radius=0.3,
        init_states=INITS,
        seed=4,
        max_steps=STEPS,
        progress=False,
    )
    with DemoFile(summary["out"]) as f:
        demos = list(f)
    assert [d.attrs["explored_steps"] for d in demos] == [[2]] * 3 + [[5]] * 3 and summary[
        "explored_per_episode"
    ] == 1.0
    assert [branch_step([2, 5], i, 3) for i in range(7)] == [2, 2, 2, 5, 5, 5, 2]
    for early, late in zip(demos[:3], demos[3:]):
        assert early.attrs["init_state_index"] == late.attrs["init_state_index"]
        # one reset seed per start: the branches share the scene's hidden fixture layout, not just the init state
        assert early.attrs["reset_seed"] == late.attrs["reset_seed"]
        assert early.attrs["fixture_layout"] == late.attrs["fixture_layout"]
        np.testing.assert_array_equal(early.states[:3], late.states[:3])  # the same scene up to the branch at step 2
        assert early.actions[2][0] != 0.0 and late.actions[2][0] == 0.0 and late.actions[5][0] != 0.0
    assert "warning" not in capsys.readouterr().err  # 6 episodes reach both points of 3 starts
    with pytest.raises(UserInputError, match="not both"):
        collect_rollouts(
            SUITE, [TASK], Lower(), str(tmp_path / "x.hdf5"), episodes=1, explore=0.1, explore_at=[2], progress=False
        )


def test_branch_points_no_episode_reaches_are_named(tmp_path, capsys):
    assert branch_points_reached([2, 5, 9], 4, 3) == [2, 5] and branch_points_reached([2, 5, 9], 9, 3) == [2, 5, 9]
    # 2 episodes from 3 starts reach only the first point; the file is still written, with one warning line
    summary = collect_rollouts(
        SUITE,
        [TASK],
        Lower(),
        str(tmp_path / "short.hdf5"),
        episodes=2,
        explore_at=[2, 5],
        trust_radius=0.3,
        init_states=INITS,
        seed=4,
        max_steps=STEPS,
        progress=False,
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "rollouts: warning: 2 episodes per task branch only at steps [2] of --explore-at [2, 5]; "
        "6 would branch every start at every point"
    ]
    assert summary["episodes"] == 2


def test_nudged_rollouts_start_apart_and_replay_from_their_records(tmp_path):
    # two episodes from one init state: without the nudge they would start identically
    summary = collect_rollouts(
        SUITE,
        [TASK],
        Lower(),
        str(tmp_path / "nudged.hdf5"),
        episodes=2,
        init_states=[3],
        seed=4,
        max_steps=STEPS,
        perturbation="init@nudge",
        progress=False,
    )
    with DemoFile(summary["out"]) as f:
        demos = list(f)
        assert f.attrs["collection"]["perturbation"] == "init@nudge"
    assert not np.array_equal(demos[0].states[0], demos[1].states[0])
    env = make_env(SUITE, TASK, seed=4, max_steps=STEPS, perturbation="init@nudge")
    for demo in demos:  # the record (reset seed, init state, perturbation) rebuilds the scene, as annotation needs
        assert [r["mode"] for r in demo.attrs["perturbation"]] == ["nudge"]
        env.reset(seed=int(demo.attrs["reset_seed"]), options={"init_state": int(demo.attrs["init_state_index"])})
        for action in demo.actions:
            env.step(action)
        np.testing.assert_array_equal(env.get_sim_state(), demo.final_state)
    env.close()


def test_rollouts_refuse_init_states_the_task_does_not_have(tmp_path):
    with pytest.raises(UserInputError, match="expected indices in 0..49"):
        collect_rollouts(SUITE, [TASK], Lower(), str(tmp_path / "x.hdf5"), episodes=1, init_states=[60], progress=False)
    assert not list(tmp_path.iterdir())  # refused before any file was made


def test_only_a_bc_policy_directory_can_be_asked_to_act_by_sampling(tmp_path):
    with pytest.raises(
        UserInputError, match="policy act 'sample' applies to a BC policy directory; a Lower decides its own actions"
    ):
        collect_rollouts(
            SUITE, [TASK], Lower(), str(tmp_path / "x.hdf5"), episodes=1, policy_act="sample", progress=False
        )
    assert not list(tmp_path.iterdir())


def test_index_ranges_parse_and_bad_ones_are_refused_in_one_line(capsys):
    import argparse

    from base_suites.runtime.settings import index_list
    from elegant.cli import main

    assert index_list("0-3,7, 9-10") == (0, 1, 2, 3, 7, 9, 10) and index_list("2,0,1") == (2, 0, 1)
    for bad, message in (("3-", "expected indices and ranges"), ("9-5", "runs backwards"), ("a", "expected indices")):
        with pytest.raises(argparse.ArgumentTypeError, match=message):
            index_list(bad)
    # --tasks takes ranges as --init-states does: one parser for both, refusing in one line
    for flag in ("--tasks", "--init-states"):
        with pytest.raises(SystemExit) as exit_:
            main(["eval", "--suite", "libero_object", "--policy", "p", "--out", "o", flag, "4-1"])
        err = capsys.readouterr().err.strip().splitlines()
        assert exit_.value.code != 0 and len(err) == 1 and "runs backwards" in err[0] and flag in err[0]
