"""Lifelong results over seeds and across algorithms (no simulator: runs written as `run_lifelong` writes them)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from base_suites.runtime.errors import UserInputError
from elegant.cli import main
from elegant.evaluation.lifelong_table import aggregate_seeds, lifelong_table, read_lifelong_result
from elegant.evaluation.metrics import lifelong_metrics

K, E = 3, 4


def fake_run(algo: str, seed: int, **config_changes) -> dict:
    """A lifelong.json of K tasks with random rates (multitask: the last row of S only)."""
    rng = np.random.default_rng(1000 * seed + len(algo))
    C = rng.integers(0, 11, size=(2, K, E)) / 10
    S = np.where(np.tril(np.ones((K, K))) > 0, rng.integers(0, 11, size=(2, K, K)) / 10, np.nan)
    if algo == "multitask":
        S[:, :-1] = np.nan
    kept = [int(np.argmax(row)) for row in C[0]]

    def metrics(i: int) -> dict:
        final = float(np.mean(S[i, -1]))
        if algo == "multitask":
            return {"fwt": float(C[i].mean()), "nbt": None, "auc": None, "final_success": final}
        return {**lifelong_metrics(S[i], C[i], kept), "final_success": final}

    def matrix(M):
        return [[None if np.isnan(v) else float(v) for v in row] for row in M]

    config = {
        "format": "libero-elegant-lifelong/1",
        "algorithm": algo,
        "algorithm_settings": {"er_memory": 1000} if algo == "er" else {},
        "suite": "libero_object",
        "tasks": [0, 1, 2],
        "task_keys": ["libero_object/0", "libero_object/1", "libero_object/2"],
        "epochs": 3,
        "episodes": 2,
        "seed": seed,
        **config_changes,
    }
    return {
        "config": config,
        "S": matrix(S[0]),
        "C": C[0].tolist(),
        "S_elegant": matrix(S[1]),
        "C_elegant": C[1].tolist(),
        "metrics": metrics(0),
        "metrics_elegant": metrics(1),
        "kept_epochs": [10 * i for i in kept],  # the evaluations are every 10 epochs
    }


def write_seeds(directory, algo: str, seeds=(0, 1, 2), **config_changes):
    """A directory as `run_lifelong_seeds` leaves it (the per-seed runs and their aggregate)."""
    results = [fake_run(algo, s, **config_changes) for s in seeds]
    directory.mkdir(parents=True)
    summary = {"runs": [str(directory / f"seed_{s}") for s in seeds], **aggregate_seeds(results)}
    (directory / "lifelong_seeds.json").write_text(json.dumps(summary))
    return results


def test_the_aggregate_over_seeds_recomputed_by_hand():
    results = [fake_run("er", s) for s in (0, 1, 2)]
    summary = aggregate_seeds(results)
    assert summary["seeds"] == [0, 1, 2] and "seed" not in summary["config"]
    for source in ("metrics", "metrics_elegant"):
        for key in ("fwt", "nbt", "auc", "final_success"):
            values = [r[source][key] for r in results]
            mean = sum(values) / 3
            std = (sum((v - mean) ** 2 for v in values) / 2) ** 0.5
            assert summary[source][key]["mean"] == pytest.approx(mean)
            assert summary[source][key]["std"] == pytest.approx(std)
            assert summary[source][key]["values"] == values
    mean_S = np.mean([[[np.nan if v is None else v for v in row] for row in r["S"]] for r in results], axis=0)
    assert summary["S_mean"][2][1] == pytest.approx(mean_S[2, 1]) and summary["S_mean"][0][1] is None


def test_one_seed_has_no_spread_and_multitask_has_no_nbt():
    one = aggregate_seeds([fake_run("seql", 4)])
    assert one["metrics"]["fwt"]["std"] is None and one["seeds"] == [4]
    mtl = aggregate_seeds([fake_run("multitask", s) for s in (0, 1)])
    assert mtl["metrics"]["nbt"] == {"mean": None, "std": None, "values": [None, None]}
    assert mtl["metrics"]["final_success"]["std"] is not None


def test_stalled_stages_count_the_tasks_that_kept_their_starting_network(tmp_path):
    results = [fake_run("packnet", s) for s in (0, 1, 2)]
    for result, kept in zip(results, ([0, 10, 0], [20, 30, 10], [0, 0, 0])):
        result["kept_epochs"] = kept
    summary = aggregate_seeds(results)
    assert summary["stalled_stages"]["values"] == [2, 0, 3]
    assert summary["stalled_stages"]["mean"] == pytest.approx(5 / 3)
    assert aggregate_seeds([fake_run("multitask", 0)])["stalled_stages"]["mean"] is None
    # an aggregate written before the count existed: the table counts from its seed runs
    directory = tmp_path / "packnet"
    for seed, result in zip((0, 1, 2), results):
        (directory / f"seed_{seed}").mkdir(parents=True)
        (directory / f"seed_{seed}" / "lifelong.json").write_text(json.dumps(result))
    before = {k: v for k, v in summary.items() if k != "stalled_stages"}
    (directory / "lifelong_seeds.json").write_text(json.dumps({"runs": [], **before}))
    table = lifelong_table([directory], tmp_path / "table")
    assert table["algorithms"][0]["stalled_stages"]["values"] == [2, 0, 3]
    row = next(line for line in table["markdown"].splitlines() if line.startswith("| PackNet"))
    assert row.rstrip(" |").endswith("1.667 ± 1.528")


def test_seeds_of_different_runs_are_refused():
    with pytest.raises(UserInputError, match="seed 1: its 'episodes' is 5 but the first run's is 2"):
        aggregate_seeds([fake_run("seql", 0), fake_run("seql", 1, episodes=5)])


def test_table_puts_algorithms_side_by_side_in_libero_order(tmp_path):
    runs = {algo: write_seeds(tmp_path / algo, algo) for algo in ("packnet", "seql", "multitask", "er")}
    table = lifelong_table([tmp_path / a for a in ("packnet", "seql", "multitask", "er")], tmp_path / "table")
    assert [a["algorithm"] for a in table["algorithms"]] == ["seql", "er", "packnet", "multitask"]
    er = table["algorithms"][1]
    assert er["metrics"]["auc"]["mean"] == pytest.approx(np.mean([r["metrics"]["auc"] for r in runs["er"]]))
    assert er["algorithm_settings"] == {"er_memory": 1000}
    saved = json.loads((tmp_path / "table" / "table.json").read_text())
    assert saved == json.loads(json.dumps({k: v for k, v in table.items() if k != "markdown"}))
    assert [a["algorithm"] for a in saved["algorithms"]] == ["seql", "er", "packnet", "multitask"]
    markdown = (tmp_path / "table" / "table.md").read_text()
    assert markdown == table["markdown"]
    row = next(line for line in markdown.splitlines() if line.startswith("| experience replay"))
    spread = er["metrics_elegant"]["fwt"]
    assert f"{spread['mean']:.3f} ± {spread['std']:.3f}" in row
    for name in ("algorithms.png", "success_matrices.png"):
        assert (tmp_path / "table" / name).stat().st_size > 0


def test_table_reads_a_single_run_as_one_seed(tmp_path):
    (tmp_path / "one").mkdir()
    result = fake_run("ewc", 0)
    (tmp_path / "one" / "lifelong.json").write_text(json.dumps(result))
    summary = read_lifelong_result(tmp_path / "one")
    assert summary["seeds"] == [0] and summary["metrics"]["nbt"]["mean"] == result["metrics"]["nbt"]


def test_table_refusals(tmp_path, capsys):
    write_seeds(tmp_path / "seql", "seql")
    write_seeds(tmp_path / "er", "er", episodes=5)
    write_seeds(tmp_path / "ewc", "ewc", seeds=(0, 1))
    write_seeds(tmp_path / "seql2", "seql")
    (tmp_path / "empty").mkdir()
    with pytest.raises(UserInputError, match="its 'episodes' is 5 but the first run's is 2"):
        lifelong_table([tmp_path / "seql", tmp_path / "er"], tmp_path / "t")
    with pytest.raises(UserInputError, match=r"seeds \[0, 1\] but"):
        lifelong_table([tmp_path / "seql", tmp_path / "ewc"], tmp_path / "t")
    with pytest.raises(UserInputError, match="two runs of seql"):
        lifelong_table([tmp_path / "seql", tmp_path / "seql2"], tmp_path / "t")
    with pytest.raises(UserInputError, match="holds no finished lifelong run"):
        lifelong_table([tmp_path / "empty"], tmp_path / "t")
    assert not (tmp_path / "t").exists()
    lifelong_table([tmp_path / "seql"], tmp_path / "t")
    assert main(["lifelong-table", str(tmp_path / "seql"), "--out", str(tmp_path / "t")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "table.json: exists" in err
    assert main(["lifelong-table", str(tmp_path / "seql"), "--out", str(tmp_path / "t"), "--overwrite"]) == 0


def test_a_run_from_before_a_setting_tables_beside_a_new_one_as_it_ran(tmp_path):
    """An old run's record lacks the settings added since (here the encoding and the batch size): it
    compares as the run it was, so it tables beside a new run of those settings, not beside another."""
    write_seeds(tmp_path / "old", "seql")
    write_seeds(tmp_path / "new", "er", encoding="task-onehot", batch_size=256, pretrained=None, modes=5)
    write_seeds(tmp_path / "goal", "ewc", encoding="goal-relative", batch_size=256, pretrained=None, modes=5)
    table = lifelong_table([tmp_path / "old", tmp_path / "new"], tmp_path / "t")
    assert [a["algorithm"] for a in table["algorithms"]] == ["seql", "er"]
    with pytest.raises(UserInputError, match="its 'encoding' is 'goal-relative' but the first run's is 'task-onehot'"):
        lifelong_table([tmp_path / "old", tmp_path / "goal"], tmp_path / "t2")
