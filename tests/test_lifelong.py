"""`elegant lifelong` on the real simulator: LIBERO's protocol with sequential fine-tuning, at tiny sizes.

Two libero_object tasks with one scripted demo each, 2 epochs per task evaluated every epoch with one
5-step episode: the numbers are all failures, but the files, the matrix shapes, the metrics, the chain
of networks from one stage to the next, resume and the refusals are the real ones.
"""

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch

from annotations.collect import collect_demos
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.jobs import Workers
from elegant.cli import main
from elegant.evaluation.lifelong import run_lifelong
from elegant.evaluation.metrics import lifelong_metrics
from elegant.policies.bc_train import snapshot_dir
from elegant.policies.continual import WeightMasks

pytestmark = pytest.mark.sim
SUITE, TASKS = "libero_object", [0, 1]
SETTINGS = {"epochs": 2, "eval_every": 1, "episodes": 1, "seed": 0, "max_steps": 5, "progress": False}


@pytest.fixture(scope="module")
def demos(tmp_path_factory) -> str:
    path = str(tmp_path_factory.mktemp("demos") / "demos.hdf5")
    collect_demos(SUITE, TASKS, path, episodes=1, quality="clean", seed=0, progress=False)
    return path


@pytest.fixture(scope="module")
def run(demos, tmp_path_factory):
    out = tmp_path_factory.mktemp("lifelong") / "run"
    return out, run_lifelong(SUITE, TASKS, [demos], out, **SETTINGS)


def weights(policy_dir) -> dict:
    return torch.load(os.path.join(policy_dir, "model.pt"), weights_only=True)


def same(a: dict, b: dict) -> bool:
    return all(torch.equal(a[k], b[k]) for k in a)


def test_matrices_metrics_and_files(run):
    out, result = run
    assert json.loads((out / "lifelong.json").read_text()) == json.loads(json.dumps(result))
    S, C = np.array(result["S"], dtype=float), np.array(result["C"], dtype=float)
    S_el, C_el = np.array(result["S_elegant"], dtype=float), np.array(result["C_elegant"], dtype=float)
    assert S.shape == S_el.shape == (2, 2) and C.shape == C_el.shape == (2, 3)
    assert result["S"][0][1] is None and not np.isnan(S[np.tril_indices(2)]).any()
    kept = [int(np.argmax(row)) for row in C]
    assert result["metrics"] == {**lifelong_metrics(S, C), "final_success": S[1].mean()}
    assert result["metrics_elegant"] == {**lifelong_metrics(S_el, C_el, kept), "final_success": S_el[1].mean()}
    assert result["config"]["eval_epochs"] == [0, 1, 2]
    for k in range(2):  # the kept checkpoint is the first best of the learning curve, and S[k, k] is its success
        best = int(np.argmax(C[k]))
        assert result["kept_epochs"][k] == best and S[k, k] == C[k, best] and S_el[k, k] == C_el[k, best]
        assert result["kept_policies"][k] == snapshot_dir(str(out / "stages" / f"task_{k}"), best)
        for epoch in range(3):
            assert (out / "evals" / f"task_{k}" / f"epoch_{epoch}" / "summary.json").exists()
    after = json.loads((out / "evals" / "after_task_1" / "summary.json").read_text())
    assert after["config"]["tasks"] == [0] and after["config"]["mode"] == "base" and after["config"]["critic"] is None
    assert S[1, 0] == after["per_task"]["libero_object/0"]["success_rate"]
    for name in ("report.md", "success_matrix.png", "learning_curves.png"):
        assert (out / name).stat().st_size > 0
    assert "FWT" in (out / "report.md").read_text()


def test_one_input_encoder_over_all_tasks_and_stage_two_starts_from_stage_one(run):
    out, result = run
    stage0, stage1 = out / "stages" / "task_0", out / "stages" / "task_1"
    configs = [json.loads((stage / "config.json").read_text()) for stage in (stage0, stage1)]
    for config in configs:  # both stages: the one-hot covers both tasks
        assert sorted(config["features"]["encoder"]["layouts"]) == ["libero_object/0", "libero_object/1"]
    assert configs[0]["training"]["tasks"] == ["libero_object/0"] and configs[0]["training"]["init_from"] is None
    kept0 = result["kept_policies"][0]
    assert configs[1]["training"]["tasks"] == ["libero_object/1"]
    assert configs[1]["training"]["init_from_path"] == os.path.abspath(kept0)
    assert configs[1]["features"] == configs[0]["features"]
    assert same(weights(snapshot_dir(str(stage1), 0)), weights(kept0))  # stage 2 starts from the kept network
    assert not same(weights(stage1), weights(kept0))  # and trains it


def test_resume_of_a_finished_run_reruns_nothing(run, demos):
    out, result = run
    files = [p for p in out.rglob("*") if p.name in ("checkpoint.pt", "model.pt", "summary.json", "episodes.jsonl")]
    before = {p: p.stat().st_mtime_ns for p in files}
    assert run_lifelong(SUITE, TASKS, [demos], out, resume=True, **SETTINGS) == result
    assert {p: p.stat().st_mtime_ns for p in files} == before


def test_resume_after_a_kill_in_stage_two_gives_the_same_numbers(run, demos, tmp_path):
    """Also determinism: retraining stage two and re-running evaluations reproduce every number."""
    out, result = run
    cut = tmp_path / "cut"
    shutil.copytree(out, cut)
    for lost in ("stages/task_1", "evals/task_1", "evals/after_task_1", "lifelong.json"):
        shutil.rmtree(cut / lost) if (cut / lost).is_dir() else (cut / lost).unlink()
    shutil.rmtree(cut / "evals" / "task_0" / "epoch_2")  # an evaluation of stage one is lost too
    again = run_lifelong(SUITE, TASKS, [demos], cut, resume=True, **SETTINGS)
    for key in ("S", "C", "S_elegant", "C_elegant", "kept_epochs", "metrics", "metrics_elegant"):
        assert again[key] == result[key], key
    # The retrained stage is the same network, bit for bit (the rates alone are all zero at this size).
    retrained, original = (d / "stages" / "task_1" / "model.pt" for d in (cut, out))
    assert retrained.read_bytes() == original.read_bytes()


def test_refusals(run, demos, tmp_path):
    out, _ = run
    with pytest.raises(UserInputError, match=r"demos\.hdf5: no demos of task libero_object/2"):
        run_lifelong(SUITE, [0, 2], [demos], tmp_path / "a", **SETTINGS)
    with pytest.raises(UserInputError, match="eval_every must be a positive integer, got 0"):
        run_lifelong(SUITE, TASKS, [demos], tmp_path / "b", **{**SETTINGS, "eval_every": 0})
    with pytest.raises(UserInputError, match="multiple of eval_every"):
        run_lifelong(SUITE, TASKS, [demos], tmp_path / "c", **{**SETTINGS, "eval_every": 3})
    with pytest.raises(UserInputError, match="listed more than once"):
        run_lifelong(SUITE, [1, 1], [demos], tmp_path / "d", **SETTINGS)
    with pytest.raises(UserInputError, match="--workers must be >= 1"):
        run_lifelong(SUITE, TASKS, [demos], tmp_path / "e", workers=0, **SETTINGS)
    with pytest.raises(UserInputError, match="not empty"):
        run_lifelong(SUITE, TASKS, [demos], out, **SETTINGS)
    with pytest.raises(UserInputError, match="field 'episodes'"):
        run_lifelong(SUITE, TASKS, [demos], out, resume=True, **{**SETTINGS, "episodes": 2})
    assert not any((tmp_path / d).exists() for d in "abcde")  # refused before any work


def test_cli_refuses_in_one_line(demos, tmp_path, capsys):
    args = [
        "lifelong",
        "--suite",
        SUITE,
        "--tasks",
        "0,1",
        demos,
        "--out",
        str(tmp_path / "x"),
        "--epochs",
        "2",
        "--eval-every",
        "0",
    ]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "eval_every must be a positive integer" in err


def test_cli_hands_the_worker_count_and_the_device_to_the_run(demos, tmp_path, monkeypatch):
    import elegant.evaluation.lifelong
    from base_suites.runtime.compute import ComputeConfig

    seen = {}
    monkeypatch.setattr(
        elegant.evaluation.lifelong,
        "run_lifelong",
        lambda *a, **kw: seen.update(kw) or {"metrics": {}, "metrics_elegant": {}},
    )
    assert (
        main(["lifelong", "--suite", SUITE, "--tasks", "0,1", demos, "--out", str(tmp_path / "w"), "--workers", "2"])
        == 0
    )
    assert seen["workers"] == Workers(2) and seen["compute"] == ComputeConfig()
    args = ["lifelong", "--suite", SUITE, "--tasks", "0,1", demos, "--out", str(tmp_path / "w"), "--device", "cpu"]
    assert main(args) == 0 and seen["compute"] == ComputeConfig(device="cpu")


def test_a_run_from_before_the_mixture_size_batch_size_and_algorithm_settings_resumes(demos, tmp_path):
    out = tmp_path / "old"
    old = {**SETTINGS, "modes": 5, "batch_size": 256}
    result = run_lifelong(SUITE, TASKS, [demos], out, **old)
    config = json.loads((out / "config.json").read_text())
    del config["modes"]  # as written before `modes` was recorded, when every run used 5
    del config["batch_size"]  # ... before the batch size was, when stages trained in batches of 256
    del config["algorithm_settings"]  # ... and before the other algorithms, when SeqL was "sequential"
    config["algorithm"] = "sequential"
    config["format"] = "libero-elegant-lifelong/1"  # the format of those records
    (out / "config.json").write_text(json.dumps(config))
    with pytest.raises(UserInputError, match="field 'modes' is 5 but this run has 16"):
        run_lifelong(SUITE, TASKS, [demos], out, resume=True, **{**SETTINGS, "batch_size": 256})
    with pytest.raises(UserInputError, match="field 'batch_size' is 256 but this run has 32"):
        run_lifelong(SUITE, TASKS, [demos], out, resume=True, **{**SETTINGS, "modes": 5})
    assert run_lifelong(SUITE, TASKS, [demos], out, resume=True, **old)["metrics"] == result["metrics"]


# ---- the other algorithms: each on the same tiny real run -----------------------------------------------


def run_algorithm(demos, out, algo: str, **extra) -> dict:
    return run_lifelong(SUITE, TASKS, [demos], out, **{**SETTINGS, **extra}, algo=algo)


def training(policy_dir) -> dict:
    return json.loads((policy_dir / "config.json").read_text())["training"]


def test_er_replays_the_first_task_while_learning_the_second(demos, tmp_path):
    from elegant.policies.bc_data import load_demos
    from elegant.policies.continual import memory_digest, replay_memory

    out = tmp_path / "er"
    result = run_algorithm(demos, out, "er", er_memory=3)
    assert result["config"]["algorithm_settings"] == {"er_memory": 3}
    assert training(out / "stages" / "task_0")["continual"] is None
    memory = replay_memory(load_demos([demos]), ["libero_object/0"], 3)
    assert training(out / "stages" / "task_1")["continual"]["replay"] == memory_digest(memory)


def test_ewc_anchors_each_stage_at_the_network_kept_before_it(demos, tmp_path):
    from elegant.policies.continual import ElasticAnchor

    out = tmp_path / "ewc"
    result = run_algorithm(demos, out, "ewc")
    assert result["config"]["algorithm_settings"] == {"ewc_lambda": 5e4, "ewc_gamma": 0.9}
    anchor = ElasticAnchor.load(str(out / "stages" / "task_0" / "ewc_anchor.pt"), 5e4)
    assert same(anchor.anchor, {k: v for k, v in weights(result["kept_policies"][0]).items()})
    assert training(out / "stages" / "task_1")["continual"]["anchor"] == anchor.digest()
    assert (out / "stages" / "task_1" / "ewc_anchor.pt").exists()


def test_packnet_keeps_the_first_tasks_weights_and_evaluates_it_with_them(demos, tmp_path):
    out = tmp_path / "packnet"
    result = run_algorithm(demos, out, "packnet", packnet_epochs=2)
    assert result["config"]["algorithm_settings"] == {"packnet_prune": 0.75, "packnet_epochs": 2}
    stage1 = out / "stages" / "task_1"
    assert result["kept_policies"][1].startswith(str(stage1 / "post"))
    # Stage 1 trained the weights task 0 left free, and no other.
    after_task_0 = WeightMasks.load(str(out / "stages" / "task_0" / "pruned" / "packnet_masks.pt"), 0)
    first, trained = weights(result["kept_policies"][0]), weights(stage1)
    for name, owner in after_task_0.owner.items():
        assert torch.equal(trained[name][owner == 1], first[name][owner == 1])
        assert (first[name][owner == 0] == 0).all()
    assert any(not torch.equal(trained[n][o == 0], first[n][o == 0]) for n, o in after_task_0.owner.items())
    # Task 0 is evaluated after task 1 with task 0's weights only.
    masks = WeightMasks.load(str(stage1 / "pruned" / "packnet_masks.pt"), 1)
    second, for_task_0 = weights(result["kept_policies"][1]), weights(stage1 / "for_task_0")
    for name, owner in masks.owner.items():
        assert torch.equal(second[name][owner == 1], first[name][owner == 1])
        assert torch.equal(for_task_0[name][owner == 1], first[name][owner == 1])
        assert (for_task_0[name][owner != 1] == 0).all()
    after = json.loads((out / "evals" / "after_task_1" / "task_0" / "summary.json").read_text())
    assert after["config"]["policy"] == str(stage1 / "for_task_0")
    assert result["S"][1][0] == after["per_task"]["libero_object/0"]["success_rate"]
    for epoch in (0, 1, 2):  # the fine-tuning after pruning is evaluated, and its best checkpoint kept
        assert (out / "evals" / "task_1" / f"post_epoch_{epoch}" / "summary.json").exists()


def test_multitask_learns_all_tasks_at_once_and_fills_the_last_row(demos, tmp_path):
    out = tmp_path / "multitask"
    result = run_algorithm(demos, out, "multitask")
    S, C = np.array(result["S"], dtype=float), np.array(result["C"], dtype=float)
    assert np.isnan(S[0]).all() and not np.isnan(S[1]).any() and C.shape == (2, 3)
    best = int(np.argmax(C.mean(axis=0)))
    assert (S[1] == C[:, best]).all() and result["kept_epochs"] == [best, best]
    assert result["metrics"]["nbt"] is None and result["metrics"]["auc"] is None
    assert result["metrics"]["final_success"] == S[1].mean()
    config = json.loads((out / "stages" / "all_tasks" / "config.json").read_text())
    assert config["training"]["tasks"] == ["libero_object/0", "libero_object/1"]
    summary = json.loads((out / "evals" / "all_tasks" / "epoch_0" / "summary.json").read_text())
    assert summary["config"]["tasks"] == [0, 1]
    assert "MTL" in (out / "report.md").read_text()


def test_an_unknown_algorithm_or_setting_is_refused_before_any_work(demos, tmp_path):
    with pytest.raises(UserInputError, match="unknown lifelong algorithm 'agem'"):
        run_algorithm(demos, tmp_path / "a", "agem")
    with pytest.raises(UserInputError, match="packnet_prune must be in"):
        run_algorithm(demos, tmp_path / "b", "packnet", packnet_prune=1.0)
    with pytest.raises(UserInputError, match="packnet_epochs .3. must be a multiple of eval_every"):
        run_algorithm(demos, tmp_path / "c", "packnet", packnet_epochs=3, eval_every=2)
    assert not any((tmp_path / d).exists() for d in "abc")


def test_seeds_from_the_command_line_repeat_the_single_run_per_seed(run, demos, tmp_path, capsys):
    _, single = run
    out = tmp_path / "seeds"
    args = ["lifelong", "--suite", SUITE, "--tasks", "0,1", demos, "--out", str(out), "--epochs", "2"]
    args += ["--eval-every", "1", "--episodes", "1", "--max-steps", "5", "--seeds", "0,1"]
    assert main(args) == 0
    summary = json.loads((out / "lifelong_seeds.json").read_text())
    assert summary["seeds"] == [0, 1] and summary["runs"] == [str(out / "seed_0"), str(out / "seed_1")]
    seed0 = json.loads((out / "seed_0" / "lifelong.json").read_text())
    for key in ("S", "C", "S_elegant", "C_elegant", "metrics", "metrics_elegant", "kept_epochs"):
        assert seed0[key] == single[key], key  # same seed, same numbers
    assert json.loads((out / "seed_1" / "config.json").read_text())["seed"] == 1
    assert (out / "report.md").exists() and (out / "success_matrix.png").exists()
    capsys.readouterr()
    assert main([*args, "--seed", "3", "--resume"]) == 2
    assert "--seed for one run or --seeds for several" in capsys.readouterr().err
    assert main([*args[:-2], "--seeds", "0,2", "--resume"]) == 2
    assert "seeds [0, 1] but this run has [0, 2]" in capsys.readouterr().err
    assert main(args) == 2  # a finished output is not started again
    assert "seeds.json: exists" in capsys.readouterr().err
    single = [a if a != str(out) else str(run[0]) for a in args]
    assert main([*single, "--resume"]) == 2
    assert "holds a single lifelong run (config.json); resume it without --seeds" in capsys.readouterr().err
    bad = [a if a != "0,1" else "0,2" for a in args[:-2]] + ["--seeds", "0,1"]
    bad[bad.index(str(out))] = str(tmp_path / "bad")
    assert main(bad) == 2 and "no demos of task libero_object/2" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_task_order_follows_libero(demos, tmp_path, capsys):
    from base_suites import task_order

    assert task_order("libero_object", 0) == list(range(10))
    assert task_order("libero_object", 1) == [4, 6, 8, 7, 3, 1, 2, 0, 9, 5]
    with pytest.raises(UserInputError, match="expected an index in 0..20"):
        task_order("libero_object", 21)
    args = ["lifelong", "--suite", "libero_90", "--task-order", "1", demos, "--out", str(tmp_path / "o")]
    assert main(args) == 2
    assert "LIBERO orders the tasks of libero_spatial" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_the_table_script_runs_every_algorithm_and_tables_them(demos, tmp_path):
    import subprocess
    import sys

    script = os.path.join(os.path.dirname(__file__), os.pardir, "scripts", "lifelong_table.sh")
    elegant = {**os.environ, "ELEGANT": f"{sys.executable} -m elegant.cli"}

    def table_script(out, *options, jobs="1"):
        return subprocess.run(
            ["bash", script, SUITE, demos, str(out), *options],
            env={**elegant, "JOBS": jobs},
            capture_output=True,
            text=True,
        )

    out = tmp_path / "all"
    options = ["--tasks", "0,1", "--epochs", "1", "--eval-every", "1", "--episodes", "1", "--max-steps", "5"]
    done = table_script(out, *options, "--packnet-epochs", "1", jobs="2")  # two algorithms at a time
    assert done.returncode == 0, done.stderr[-2000:]
    table = json.loads((out / "table" / "table.json").read_text())
    assert [a["algorithm"] for a in table["algorithms"]] == ["seql", "er", "ewc", "packnet", "multitask"]
    assert table["config"]["epochs"] == 1 and table["config"]["task_keys"] == ["libero_object/0", "libero_object/1"]
    assert "| PackNet |" in (out / "table" / "table.md").read_text()
    assert '"final_success"' in (out / "seql.log").read_text()  # each algorithm's own log
    for jobs in ("1", "2"):  # a refusal leaves nothing behind, run one by one or side by side
        refused = table_script(tmp_path / f"bad{jobs}", "--tasks", "0,9", jobs=jobs)
        assert refused.returncode != 0 and "no demos of task libero_object/9" in refused.stderr
        assert not (tmp_path / f"bad{jobs}").exists()
    assert table_script(tmp_path / "x", jobs="two").stderr.startswith("JOBS: expected a whole number")
    usage = subprocess.run(["bash", script, SUITE], capture_output=True, text=True)
    assert usage.returncode == 2 and usage.stderr.startswith("usage:")


def test_pretrained_policy_starts_the_sequence_with_its_hidden_layers_and_head(demos, tmp_path):
    from elegant.policies.bc_train import FineTuning, train_policy

    pretrained = str(tmp_path / "pretrained")  # trained on another task, as LIBERO-100 pre-trains on libero_90
    train_policy(
        [demos], pretrained, epochs=1, chunk=1, fine_tuning=FineTuning(tasks=["libero_object/1"]), progress=False
    )
    out = tmp_path / "lib100"
    result = run_lifelong(SUITE, TASKS, [demos], out, pretrained=pretrained, **SETTINGS)
    source, start = weights(pretrained), weights(snapshot_dir(str(out / "stages" / "task_0"), 0))
    for name in ("trunk.2.weight", "trunk.2.bias", "head.means.weight", "head.logits.bias"):
        assert torch.equal(start[name], source[name]), name
    assert start["trunk.0.weight"].shape != source["trunk.0.weight"].shape  # the input covers other tasks
    sha = json.loads((tmp_path / "pretrained" / "config.json").read_text())["model_sha256"]
    assert result["config"]["pretrained"] == {"path": pretrained, "model_sha256": sha}
    with pytest.raises(UserInputError, match="missing: no such policy directory"):
        run_lifelong(SUITE, TASKS, [demos], tmp_path / "x", pretrained=str(tmp_path / "missing"), **SETTINGS)
    assert not (tmp_path / "x").exists()


def test_a_goal_relative_pretrained_policy_carries_over_whole_and_another_encoding_is_refused(demos, tmp_path):
    """With the goal-relative input every layer fits: the first stage starts from all of the pretrained
    network (trained on another task) and reads its input through the pretrained normalisation."""
    from elegant.policies.bc_train import FineTuning, train_policy

    pretrained = str(tmp_path / "pretrained")
    train_policy(
        [demos],
        pretrained,
        epochs=1,
        chunk=1,
        obs_noise=0.0,
        encoding="goal-relative",
        fine_tuning=FineTuning(tasks=["libero_object/1"]),
        progress=False,
    )
    out = tmp_path / "goal"
    result = run_lifelong(SUITE, TASKS, [demos], out, pretrained=pretrained, encoding="goal-relative", **SETTINGS)
    source, start = weights(pretrained), weights(snapshot_dir(str(out / "stages" / "task_0"), 0))
    assert source.keys() == start.keys() and same(source, start)
    stage = json.loads((out / "stages" / "task_0" / "config.json").read_text())
    assert stage["features"] == json.loads((tmp_path / "pretrained" / "config.json").read_text())["features"]
    assert result["config"]["encoding"] == "goal-relative"
    with pytest.raises(UserInputError, match="input encoding is goal-relative but this run has task-onehot"):
        run_lifelong(SUITE, TASKS, [demos], tmp_path / "x", pretrained=pretrained, **SETTINGS)
    chunked = str(tmp_path / "chunked")  # a head of 8-step chunks would not carry over: refused, not cut off
    train_policy([demos], chunked, epochs=1, encoding="goal-relative", progress=False)
    with pytest.raises(UserInputError, match="model.chunk is 8 but lifelong stage policies have 1"):
        run_lifelong(SUITE, TASKS, [demos], tmp_path / "x", pretrained=chunked, encoding="goal-relative", **SETTINGS)
    assert not (tmp_path / "x").exists()


def test_packnet_capacity_benchmark_trains_its_probes_under_their_masks(demos, run, tmp_path):
    packnet = tmp_path / "packnet" / "seed_0"
    run_algorithm(demos, packnet, "packnet", packnet_epochs=1)
    script = os.path.join(os.path.dirname(__file__), os.pardir, "benchmarks", "packnet_capacity.py")
    command = [sys.executable, script, str(packnet), str(run[0]), "--out", str(tmp_path / "probes")]
    command += ["--task", "1", "--fractions", "1,0.5"]
    done = subprocess.run(command, capture_output=True, text=True, check=True)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert [len(v) for v in result["stage_log_likelihood"].values()] == [2, 2]  # two runs of two stages
    assert set(result["probe_log_likelihood"]["sparse"]) == {"1.0", "0.5"}
    assert set(result["probe_log_likelihood"]["packlike"]) == {"0.5"}  # no packlike probe of the dense net
    assert all(np.isfinite(v) for p in result["probe_log_likelihood"].values() for v in p.values())
    for variant in ("sparse", "packlike"):  # the weights held fixed do not move; some free ones do
        probe = tmp_path / "probes" / f"{variant}_0.5"
        start, trained = weights(f"{probe}_start"), weights(probe)
        held = WeightMasks.load(str(tmp_path / "probes" / f"{variant}_0.5_start" / "packnet_masks.pt"), 0).owner
        assert all(torch.equal(trained[n][o == 1], start[n][o == 1]) for n, o in held.items())
        assert any(not torch.equal(trained[n][o == 0], start[n][o == 0]) for n, o in held.items())
