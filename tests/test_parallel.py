"""Episodes on worker processes (`base_suites.runtime.jobs`): the runner's contract with toy jobs, then the real
collectors, whose files must not depend on the number of workers."""

import os
import time
from functools import partial

import h5py
import numpy as np
import pytest

from annotations import annotate_file
from annotations.collect import collect_demos
from base_suites import UserInputError
from base_suites.runtime.jobs import check_workers, in_order, run_jobs
from elegant.evaluation.episode_log import run_records


class Doubler:
    """A worker that remembers which process it runs in and how many jobs it did (state kept between jobs);
    with `marks` it leaves a file per job started, and with `pause` it takes that long per job."""

    def __init__(self, fail_at=(), marks=None, pause=0.0, slow=()):
        self.fail_at, self.marks, self.pause, self.slow, self.done = fail_at, marks, pause, slow, 0

    def __call__(self, job):
        if self.marks:
            open(os.path.join(self.marks, str(job)), "w").close()
        time.sleep(0.5 if job in self.slow else self.pause)
        if job in self.fail_at:
            raise UserInputError(f"job {job} is bad")
        self.done += 1
        return job * 2, os.getpid(), self.done


class BrokenFactory:
    def __init__(self):
        raise UserInputError("policy/: no such directory")


def results_of(factory, jobs, workers):
    with run_jobs(factory, jobs, workers) as results:
        return list(results)


def test_one_worker_runs_in_this_process_in_order_and_keeps_its_state():
    results = results_of(Doubler, [3, 1, 2], workers=1)
    assert [(job, value) for job, (value, _, _) in results] == [(3, 6), (1, 2), (2, 4)]
    assert {pid for _, (_, pid, _) in results} == {os.getpid()}
    assert [done for _, (_, _, done) in results] == [1, 2, 3]


def test_two_workers_give_every_result_from_other_processes():
    results = dict(results_of(Doubler, list(range(8)), workers=2))
    assert {job: value for job, (value, _, _) in results.items()} == {j: 2 * j for j in range(8)}
    pids = {pid for _, pid, _ in results.values()}
    assert os.getpid() not in pids and 1 <= len(pids) <= 2
    # each worker is built once and kept: its job counter runs over all the jobs it did
    for pid in pids:
        counts = sorted(done for _, p, done in results.values() if p == pid)
        assert counts == list(range(1, len(counts) + 1))


def test_errors_in_a_job_or_in_building_a_worker_reach_the_caller_as_they_were_raised():
    with pytest.raises(UserInputError, match="job 2 is bad"):
        results_of(partial(Doubler, fail_at=(2,)), list(range(6)), workers=2)
    for workers in (1, 2):
        with pytest.raises(UserInputError, match="policy/: no such directory"):
            results_of(BrokenFactory, [0, 1], workers=workers)


def test_when_jobs_fail_the_first_failure_is_raised_after_every_earlier_result():
    """Job 5 fails first in time, job 2 (slow) later: as a serial run, the caller gets jobs 0 and 1 and
    then job 2's error, whatever the timing, and the worker's traceback as its cause."""
    seen = []
    with pytest.raises(UserInputError, match="job 2 is bad") as raised:
        with run_jobs(partial(Doubler, fail_at=(2, 5), slow=(2,)), list(range(8)), workers=2) as results:
            seen.extend(job for job, _ in results)
    assert {0, 1} <= set(seen) and 2 not in seen and 5 not in seen
    assert "job 2 is bad" in str(raised.value.__cause__)  # the remote traceback


def test_leaving_the_run_early_stops_the_workers(tmp_path):
    jobs = list(range(40))
    with run_jobs(partial(Doubler, marks=str(tmp_path), pause=0.2), jobs, workers=2) as results:
        for _ in results:
            break
    started = set(os.listdir(tmp_path))
    time.sleep(1.0)
    assert set(os.listdir(tmp_path)) == started  # nothing runs after the context is left
    assert len(started) < 10


def test_worker_count_and_unpicklable_factories_are_refused():
    with pytest.raises(UserInputError, match="--workers must be >= 1"):
        check_workers(0)
    with pytest.raises(UserInputError, match="cannot be sent to worker processes"):
        results_of(lambda: Doubler(), [1, 2], workers=2)
    assert results_of(lambda: Doubler(), [1], workers=2)[0][1][0] == 2  # a single job runs here: no pickling


def test_in_order_releases_results_by_position_from_the_first_missing_one():
    arrived = [(2, "c"), (0, "a"), (3, "d"), (1, "b")]
    assert [job for job, _ in in_order(arrived, lambda job: job)] == [0, 1, 2, 3]
    assert [job for job, _ in in_order([(5, "x"), (4, "y")], lambda job: job, first=4)] == [4, 5]
    assert [job for job, _ in in_order([(0, "a"), (2, "c")], lambda job: job)] == [0]  # 2 waits for 1, which never came


def test_a_runs_records_count_in_task_then_episode_order_whatever_order_they_finished_in():
    config = {"suite": "libero_goal", "tasks": [4, 1], "episodes": 2}
    finished = [
        {"task": "libero_goal/1", "episode": 1},
        {"task": "libero_goal/4", "episode": 1},
        {"task": "libero_goal/1", "episode": 0},
        {"task": "libero_goal/4", "episode": 2},
        {"task": "libero_goal/4", "episode": 0},
        {"task": "libero_goal/7", "episode": 0},
    ]
    assert [(r["task"], r["episode"]) for r in run_records(finished, config)] == [
        ("libero_goal/4", 0),
        ("libero_goal/4", 1),
        ("libero_goal/1", 0),
        ("libero_goal/1", 1),
    ]


def _contents(path):
    """Every dataset and attribute of an HDF5 file, as comparable Python values."""
    out = {}

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset):
            out[name] = np.asarray(obj[()]).tolist()
        out[name + "@attrs"] = {k: np.asarray(v).tolist() for k, v in obj.attrs.items()}

    with h5py.File(path) as f:
        f.visititems(visit)
        out["data@attrs"] = {k: np.asarray(v).tolist() for k, v in f["data"].attrs.items()}
    return out


@pytest.mark.sim
def test_demos_and_their_annotation_do_not_depend_on_the_number_of_workers(tmp_path):
    files = {}
    for workers in (1, 2):
        demos = str(tmp_path / f"demos_{workers}.hdf5")
        collect_demos(
            "libero_object",
            [0, 1],
            demos,
            episodes=2,
            quality={"tilt": 0.5, "collide": 0.5},
            seed=2,
            progress=False,
            workers=workers,
        )
        annotated = str(tmp_path / f"annotated_{workers}.hdf5")
        annotate_file(demos, annotated, progress=False, workers=workers)
        files[workers] = (_contents(demos), _contents(annotated))
    serial, parallel = files[1], files[2]
    assert len([k for k in serial[0] if k.endswith("/actions")]) == 4  # 2 tasks x 2 episodes, demo_0..demo_3
    assert serial[0] == parallel[0]
    assert serial[1] == parallel[1]
