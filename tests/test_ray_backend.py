"""The Ray backend on a local Ray with two CPUs: demo files and eval runs identical to the local backend's,
a worker killed by its own pid mid-run losing and duplicating nothing, and the refusals users hit."""

from __future__ import annotations

import json
import os
import sys

import pytest
from conftest import load_benchmark

from base_suites import UserInputError
from base_suites.runtime.jobs import Workers, check_workers

ray = pytest.importorskip("ray", reason="needs Ray (scripts/setup.sh installs the [ray] extra)")
pytestmark = pytest.mark.sim
SUITE = "libero_object"
RAY = Workers(2, "ray")


@pytest.fixture(scope="module", autouse=True)
def local_ray():
    """One local Ray for the module (started by the first job, as a command starts it), shut down after."""
    yield
    ray.shutdown()


def test_demos_and_their_annotation_on_ray_write_the_local_backends_files(tmp_path):
    from annotations import annotate_file
    from annotations.collect import collect_demos

    differences = load_benchmark("parallel_speedup").hdf5_differences
    kw = {"episodes": 3, "seed": 0, "progress": False}
    collect_demos(SUITE, [0], str(tmp_path / "local.hdf5"), workers=1, **kw)
    collect_demos(SUITE, [0], str(tmp_path / "ray.hdf5"), workers=RAY, **kw)
    assert differences(tmp_path / "local.hdf5", tmp_path / "ray.hdf5") == []
    annotate_file(str(tmp_path / "local.hdf5"), str(tmp_path / "local_ann.hdf5"), progress=False)
    annotate_file(str(tmp_path / "local.hdf5"), str(tmp_path / "ray_ann.hdf5"), progress=False, workers=RAY)
    assert differences(tmp_path / "local_ann.hdf5", tmp_path / "ray_ann.hdf5") == []


def untimed(record: dict) -> dict:
    return {k: v for k, v in record.items() if k not in ("decision_time", "env_step_time")}


def run_eval(out, workers, policy="policy_entry_points:make_policy", resume=False):
    from policy_entry_points import ReachCritic

    from elegant.evaluation.runner import evaluate

    return evaluate(SUITE, [0], policy, ReachCritic(), out=out, workers=workers, resume=resume, progress=False,
                    mode="always", episodes=4, max_steps=12, seed=0)  # fmt: skip


def episodes(out) -> list[dict]:
    return [untimed(json.loads(line)) for line in (out / "episodes_sorted.jsonl").read_text().splitlines()]


def traces(out) -> dict:
    found = {}
    for name in sorted(os.listdir(out / "traces")):
        trace = json.loads((out / "traces" / name).read_text())
        trace["decisions"].pop("time")
        found[name] = trace
    return found


@pytest.fixture(scope="module")
def local_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("eval") / "local"
    run_eval(out, Workers(2))
    return out


def test_eval_on_ray_gives_the_local_backends_episodes_and_traces_and_resumes_across_backends(local_run, tmp_path):
    run_eval(tmp_path / "ray", RAY)
    assert episodes(tmp_path / "ray") == episodes(local_run) and traces(tmp_path / "ray") == traces(local_run)
    # two episodes on one backend, the rest resumed on the other
    from policy_entry_points import ReachCritic

    from elegant.evaluation.runner import evaluate

    half = tmp_path / "half"
    evaluate(SUITE, [0], "policy_entry_points:make_policy", ReachCritic(), out=half, workers=1, progress=False,
             mode="always", episodes=2, max_steps=12, seed=0)  # fmt: skip
    run_eval(half, RAY, resume=True)
    assert episodes(half) == episodes(local_run)


def test_a_worker_killed_by_its_own_pid_loses_nothing_and_duplicates_nothing(local_run, tmp_path):
    marker = tmp_path / "killed"
    policy = f'policy_entry_points:make_self_killing:{{"marker": "{marker}"}}'
    run_eval(tmp_path / "run", RAY, policy=policy)
    assert marker.exists()  # a worker did die mid-episode
    lines = [json.loads(line) for line in (tmp_path / "run" / "episodes.jsonl").read_text().splitlines()]
    assert sorted((r["task"], r["episode"]) for r in lines) == [(f"{SUITE}/0", e) for e in range(4)]  # once each
    assert episodes(tmp_path / "run") == episodes(local_run) and traces(tmp_path / "run") == traces(local_run)


def test_a_wrong_address_or_a_local_address_is_one_line_before_anything_is_created(tmp_path, capsys):
    from elegant.cli import main

    ray.shutdown()  # as in a fresh command: connecting is what is refused
    out = tmp_path / "run"
    args = ["eval", "--suite", SUITE, "--tasks", "0", "--policy", "policy_entry_points:make_policy", "--mode", "base",
            "--episodes", "1", "--out", str(out), "--backend", "ray"]  # fmt: skip
    assert main([*args, "--ray-address", "127.0.0.1:9"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--ray-address 127.0.0.1:9: no Ray cluster answers there" in err
    assert main([*args, "--ray-address", "nonsense"]) == 2
    assert "expected HOST:PORT" in capsys.readouterr().err
    assert main([*args, "--ray-address", "auto"]) == 2  # no cluster joined on this machine
    assert "--ray-address auto: Could not find any running Ray instance" in capsys.readouterr().err
    assert not out.exists()
    with pytest.raises(UserInputError, match="--ray-address needs --backend ray"):
        check_workers(Workers(2, "local", "auto"))
    with pytest.raises(UserInputError, match="--workers must be >= 1"):
        Workers(0, "ray")


def test_the_ray_backend_without_ray_installed_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # as if the extra were not installed
    with pytest.raises(UserInputError, match=r"--backend ray needs Ray: pip install -e \.\[ray\]"):
        check_workers(RAY)
