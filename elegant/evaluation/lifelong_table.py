"""Lifelong results over seeds and side by side over algorithms, in LIBERO's table layout (docs/design.md §8.3).

`run_lifelong_seeds` runs one algorithm once per seed (OUT/seed_<s>/, each a full `run_lifelong` run) and
writes the mean and standard deviation (over seeds, n - 1 in the denominator) of FWT, NBT, AUC and the
final success, from success and from elegant success, with the mean success matrices. The seed is the
statistical unit here: it draws the network's initialisation, the batches and the evaluation starts.

`lifelong_table` reads such directories (or single runs, as one seed each), one per algorithm, refuses
runs that differ in anything but the algorithm and the seeds, and writes one table (rows: algorithms,
columns: FWT, NBT, AUC and final success, from success and from ESR, and the stalled stages), one bar plot
and the mean success matrices of every algorithm.

A stalled stage kept epoch 0: no evaluation of its task beat the network the stage started from, so
LIBERO's rule (the first best) keeps that network, and the task is not learned at all. The count tells a
method that cannot learn a new task (EWC's penalty too stiff, PackNet short of free weights) from one that
learns it and then forgets. After the first task, PackNet then prunes every weight the stalled task held
(the free weights it claimed are still zero).

OUT of `run_lifelong_seeds`::

    seeds.json                  the seeds; a resumed run must have the same
    seed_<s>/                   `run_lifelong` output with seed s
    lifelong_seeds.json         per metric: mean, std and the per-seed values; stalled stages; mean S and C
    report.md, success_matrix.png
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from base_suites.runtime.compute import ComputeConfig, use_compute
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import atomic_write_json, read_json_file
from base_suites.runtime.jobs import Workers, check_workers
from base_suites.runtime.locks import output_lock
from base_suites.runtime.outputs import check_output
from base_suites.runtime.settings import with_overrides
from elegant.evaluation.config import LifelongConfig
from elegant.evaluation.lifelong import (
    LIFELONG_RECORD,
    METRIC_KEYS,
    lifelong_inputs,
    plot_success_matrices,
    run_lifelong,
)
from elegant.evaluation.lifelong_algos import algorithm_names, lifelong_algorithm
from elegant.reporting.html import write_report
from elegant.reporting.report import markdown_table, save_figure

SEEDS_FORMAT = "libero-elegant-lifelong-seeds/1"
METRIC_LABELS = {"fwt": "FWT (↑)", "nbt": "NBT (↓)", "auc": "AUC (↑)", "final_success": "final (↑)"}
SOURCES = (("metrics", "success"), ("metrics_elegant", "elegant success (ESR)"))
STALLED_MEANING = (
    "A stalled stage kept epoch 0: no evaluation of its task beat the network it started from, so LIBERO's "
    "first-best rule keeps that network and the task is never learned."
)


def _spread(values: Sequence[float | None]) -> dict[str, Any]:
    """Mean and sample standard deviation of one metric over seeds (None where the metric is undefined,
    as NBT and AUC for multitask; std None for a single seed)."""
    if any(v is None for v in values):
        return {"mean": None, "std": None, "values": list(values)}
    array = np.asarray(values, dtype=np.float64)
    return {
        "mean": float(array.mean()),
        "std": float(array.std(ddof=1)) if len(array) > 1 else None,
        "values": [float(v) for v in array],
    }


def _mean_matrix(results: Sequence[dict[str, Any]], key: str) -> list[list[float | None]]:
    """The element-wise mean of a matrix over runs (None where the runs have none, e.g. above S's diagonal:
    runs of one algorithm on the same tasks have values in the same places)."""
    mean = np.array([[[np.nan if v is None else v for v in row] for row in r[key]] for r in results]).mean(axis=0)
    return [[None if np.isnan(v) else float(v) for v in row] for row in mean]


def stalled_stages(result: dict[str, Any]) -> int | None:
    """How many stages of one run kept epoch 0 (module docstring); None for multitask, which has no stages."""
    if result["config"]["algorithm"] == "multitask":
        return None
    return sum(epoch == 0 for epoch in result["kept_epochs"])


def aggregate_seeds(results: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Mean and std over the runs of one algorithm that differ in their seed only."""
    configs = [{k: v for k, v in r["config"].items() if k != "seed"} for r in results]
    for config, result in zip(configs[1:], results[1:]):
        _refuse_difference(configs[0], config, f"seed {result['config']['seed']}")
    return {
        "config": configs[0],
        "seeds": [r["config"]["seed"] for r in results],
        **{source: {key: _spread([r[source][key] for r in results]) for key in METRIC_KEYS} for source, _ in SOURCES},
        "stalled_stages": _spread([stalled_stages(r) for r in results]),
        **{f"{key}_mean": _mean_matrix(results, key) for key in ("S", "S_elegant", "C", "C_elegant")},
    }


def _refuse_difference(reference: dict[str, Any], other: dict[str, Any], what: str, ignore: Sequence[str] = ()) -> None:
    for key in sorted(set(reference) | set(other)):
        if key not in ignore and reference.get(key) != other.get(key):
            raise UserInputError(
                f"{what}: its {key!r} is {other.get(key)!r} but the first run's is {reference.get(key)!r}; "
                "runs compared must differ only in the algorithm and the seeds"
            )


def _cell(spread: dict[str, Any]) -> str:
    if spread["mean"] is None:
        return "—"
    return f"{spread['mean']:.3f}" + ("" if spread["std"] is None else f" ± {spread['std']:.3f}")


def run_lifelong_seeds(
    suite: str,
    tasks: Sequence[int | str],
    demo_paths: Sequence[str],
    out: str | os.PathLike,
    seeds: Sequence[int],
    config: LifelongConfig | None = None,
    *,
    progress: bool = True,
    resume: bool = False,
    workers: int | Workers = 1,
    compute: ComputeConfig | None = None,
    pretrained: str | os.PathLike | None = None,
    **settings: Any,
) -> dict[str, Any]:
    """`run_lifelong` once per seed in OUT/seed_<s>/ and their aggregate (module docstring); the settings
    are `run_lifelong`'s, whose `seed` the seeds replace. Returns the content of OUT/lifelong_seeds.json."""
    cfg = with_overrides(config or LifelongConfig(), settings, "lifelong")
    seeds = [int(s) for s in seeds]
    if not seeds or len(set(seeds)) != len(seeds) or min(seeds) < 0:
        raise UserInputError(f"lifelong: --seeds must be distinct non-negative integers, got {seeds}")
    lifelong_inputs(suite, tasks, demo_paths, cfg, pretrained)  # bad tasks or demo files are refused before OUT exists
    check_workers(workers)
    use_compute(compute or ComputeConfig(), "lifelong")
    out = Path(out)
    record = {"format": SEEDS_FORMAT, "seeds": seeds}
    check_output(str(out), "dir", resume=resume, results=("seeds.json", "config.json", "lifelong.json"))
    if (out / "config.json").exists():
        raise UserInputError(f"{out}: holds a single lifelong run (config.json); resume it without --seeds")
    with output_lock(out):
        if resume and (out / "seeds.json").exists():
            before = read_json_file(out / "seeds.json", "lifelong seeds")
            if before != record:
                raise UserInputError(
                    f"{out / 'seeds.json'}: seeds {before.get('seeds')} but this run has {seeds}; resume with the same"
                )
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(out / "seeds.json", record)
        results = [
            run_lifelong(
                suite,
                tasks,
                demo_paths,
                out / f"seed_{seed}",
                with_overrides(cfg, {"seed": seed}, "lifelong"),
                progress=progress,
                resume=resume,
                workers=workers,
                compute=compute,
                pretrained=pretrained,
            )
            for seed in seeds
        ]
        summary = {"runs": [str(out / f"seed_{s}") for s in seeds], **aggregate_seeds(results)}
        atomic_write_json(out / "lifelong_seeds.json", summary)
        _write_seeds_report(out, summary)
        return summary


def _matrices(summary: dict[str, Any]) -> np.ndarray:
    return np.array(
        [[[np.nan if v is None else v for v in row] for row in summary[key]] for key in ("S_mean", "S_elegant_mean")]
    )


def _write_seeds_report(out: Path, summary: dict[str, Any]) -> None:
    cfg = summary["config"]
    labels = [f"{k}: {key}" for k, key in enumerate(cfg["task_keys"])]
    plot_success_matrices(_matrices(summary), labels, out / "success_matrix.png")
    rows = [
        [METRIC_LABELS[key], *(_cell(summary[source][key]) for source, _ in SOURCES)]
        + [" / ".join("—" if v is None else f"{v:.3f}" for v in summary["metrics"][key]["values"])]
        for key in METRIC_KEYS
    ]
    title = lifelong_algorithm(cfg["algorithm"]).title
    lines = [
        f"# Lifelong learning: {cfg['suite']}, {title}, {len(summary['seeds'])} seed(s)",
        "",
        f"- seeds {', '.join(map(str, summary['seeds']))} (runs: {', '.join(summary['runs'])})",
        f"- tasks in learning order: {', '.join(labels)}",
        f"- {cfg['epochs']} epochs per task; {cfg['episodes']} episodes per evaluation",
        "",
        "Mean ± standard deviation over seeds (n - 1); the seed is the unit.",
        "",
        markdown_table(["metric", "from success", "from ESR", "per seed (success)"], rows),
        "",
        f"Stalled stages per seed, of {len(labels)}: "
        + " / ".join("—" if v is None else f"{v:.0f}" for v in summary["stalled_stages"]["values"]),
        STALLED_MEANING,
        "",
        "![mean success matrices](success_matrix.png)",
    ]
    write_report(out / "report.md", "\n".join(lines) + "\n")


# ---- algorithms side by side ---------------------------------------------------------------------------


def read_lifelong_result(path: str | os.PathLike) -> dict[str, Any]:
    """A finished `run_lifelong_seeds` directory, or a single `run_lifelong` run read as one seed."""
    path = Path(path)
    if (path / "lifelong_seeds.json").exists():
        summary = read_json_file(path / "lifelong_seeds.json", "lifelong seeds summary")
    elif (path / "lifelong.json").exists():
        summary = {"runs": [str(path)], **aggregate_seeds([read_json_file(path / "lifelong.json", "lifelong run")])}
    else:
        raise UserInputError(f"{path}: holds no finished lifelong run (lifelong.json or lifelong_seeds.json)")
    if "stalled_stages" not in summary:  # an aggregate from before the count: its seed runs hold what it needs
        seeds = [read_json_file(path / f"seed_{s}" / "lifelong.json", "lifelong run") for s in summary["seeds"]]
        summary["stalled_stages"] = _spread([stalled_stages(r) for r in seeds])
    config = LIFELONG_RECORD.upgrade(summary["config"], str(path))  # a run from before a setting reads as it ran
    return {"path": str(path), **summary, "config": config}


def lifelong_table(runs: Sequence[str | os.PathLike], out: str | os.PathLike, *, overwrite: bool = False) -> dict:
    """LIBERO's table of algorithms from finished lifelong runs (one per algorithm), written to OUT as
    table.json, table.md, algorithms.png and success_matrices.png. Returns the content of table.json with
    the markdown of table.md under "markdown"."""
    if not runs:
        raise UserInputError("lifelong-table: expected at least one run directory")
    summaries = [read_lifelong_result(r) for r in runs]
    ignore = ("algorithm", "algorithm_settings")
    for summary in summaries[1:]:
        _refuse_difference(summaries[0]["config"], summary["config"], summary["path"], ignore)
        if summary["seeds"] != summaries[0]["seeds"]:
            raise UserInputError(
                f"{summary['path']}: seeds {summary['seeds']} but {summaries[0]['path']} has {summaries[0]['seeds']}"
            )
    algos = [s["config"]["algorithm"] for s in summaries]
    repeated = sorted({a for a in algos if algos.count(a) > 1})
    if repeated:
        paths = [s["path"] for s in summaries if s["config"]["algorithm"] == repeated[0]]
        raise UserInputError(f"lifelong-table: two runs of {repeated[0]}: {paths[0]} and {paths[1]}")
    out = Path(out)
    check_output(str(out), "dir", resume=False, overwrite=overwrite, results=("table.json",))
    summaries.sort(key=lambda s: algorithm_names().index(s["config"]["algorithm"]))
    table = {
        "config": {k: v for k, v in summaries[0]["config"].items() if k not in ignore},
        "seeds": summaries[0]["seeds"],
        # a list, in LIBERO's order (JSON objects are written with sorted keys)
        "algorithms": [
            {
                "algorithm": s["config"]["algorithm"],
                "path": s["path"],
                "algorithm_settings": s["config"]["algorithm_settings"],
                **{source: s[source] for source, _ in SOURCES},
                "stalled_stages": s["stalled_stages"],
                "S_mean": s["S_mean"],
                "S_elegant_mean": s["S_elegant_mean"],
            }
            for s in summaries
        ],
    }
    with output_lock(out):
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(out / "table.json", table)
        _plot_algorithms(table, out / "algorithms.png")
        _plot_all_matrices(table, out / "success_matrices.png")
        markdown = _table_markdown(table)
        write_report(out / "table.md", markdown)
    return {**table, "markdown": markdown}


def _table_markdown(table: dict[str, Any]) -> str:
    cfg, algos = table["config"], table["algorithms"]
    header = [
        "algorithm",
        *(f"{METRIC_LABELS[k]} {tag}" for tag in ("success", "ESR") for k in METRIC_KEYS),
        "stalled stages (↓)",
    ]
    rows = [
        [
            lifelong_algorithm(e["algorithm"]).title,
            *(_cell(e[source][key]) for source, _ in SOURCES for key in METRIC_KEYS),
            _cell(e["stalled_stages"]),
        ]
        for e in algos
    ]
    lines = [
        f"# Lifelong learning on {cfg['suite']}: LIBERO's algorithms, success and elegant success",
        "",
        f"- tasks in learning order: {', '.join(cfg['task_keys'])}",
        f"- {cfg['epochs']} epochs per task, {cfg['episodes']} episodes per evaluation, seeds "
        f"{', '.join(map(str, table['seeds']))}: mean ± standard deviation over seeds (n - 1)",
        "- runs: " + ", ".join(f"{entry['algorithm']}: {entry['path']}" for entry in algos),
        "",
        markdown_table(header, rows),
        "",
        "Multitask learns every task at once: no NBT or AUC; its FWT is the area under its learning curves.",
        f"Stalled stages are counted of {len(cfg['task_keys'])}. {STALLED_MEANING}",
        "",
        "![algorithms](algorithms.png)",
        "",
        "![mean success matrices](success_matrices.png)",
    ]
    return "\n".join(lines) + "\n"


def _plot_algorithms(table: dict[str, Any], path: Path) -> Path:
    """Grouped bars: one group per metric, one bar per algorithm, error bars one std over seeds (none for a
    single seed); the legend sits outside the data."""
    from matplotlib.figure import Figure

    algos = table["algorithms"]
    fig = Figure(figsize=(12, 3.8), layout="constrained")
    width = 0.8 / len(algos)
    panels = fig.subplots(1, 2, sharey=True)
    for ax, (source, title) in zip(panels, SOURCES):
        for a, entry in enumerate(algos):
            spreads = [entry[source][key] for key in METRIC_KEYS]
            means = [np.nan if s["mean"] is None else s["mean"] for s in spreads]
            stds = None if all(s["std"] is None for s in spreads) else [s["std"] or 0.0 for s in spreads]
            x = np.arange(len(METRIC_KEYS)) + (a - (len(algos) - 1) / 2) * width
            ax.bar(x, means, width, yerr=stds, capsize=3 if stds else 0, label=entry["algorithm"])
        ax.set_xticks(range(len(METRIC_KEYS)), [METRIC_LABELS[k] for k in METRIC_KEYS])
        ax.set_ylim(0, 1.05)
        ax.set_ylabel("rate")
        ax.set_title(f"from {title}", fontsize=10)
    panels[-1].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return save_figure(fig, path)


def _plot_all_matrices(table: dict[str, Any], path: Path) -> Path:
    """Mean S from success (left) and ESR (right), one row per algorithm."""
    from matplotlib.figure import Figure

    algos = table["algorithms"]
    K = len(table["config"]["task_keys"])
    fig = Figure(figsize=(2 * (1.2 + 0.45 * K), len(algos) * (0.9 + 0.4 * K)), layout="constrained")
    axes = np.atleast_2d(fig.subplots(len(algos), 2, squeeze=False))
    for row, entry in zip(axes, algos):
        name = entry["algorithm"]
        for ax, key, title in zip(row, ("S_mean", "S_elegant_mean"), ("success", "ESR")):
            matrix = np.array([[np.nan if v is None else v for v in r] for r in entry[key]])
            image = ax.imshow(np.ma.masked_invalid(matrix), vmin=0.0, vmax=1.0, cmap="viridis")
            ax.set_title(f"{name}: {title}", fontsize=9)
            ax.set_xlabel("evaluated task j", fontsize=8)
            ax.set_ylabel("after task i", fontsize=8)
            ax.set_xticks(range(K))
            ax.set_yticks(range(K))
            ax.tick_params(labelsize=7)
    fig.colorbar(image, ax=axes.ravel().tolist(), shrink=0.6)
    return save_figure(fig, path)
