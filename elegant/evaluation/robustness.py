"""LIBERO-PRO's robustness table from one command, from success and from elegant success (docs/design.md §8.4).

For every suite, the original tasks and every chosen axis run as one `evaluate` run each, with the same
policy, critic, mode, episodes and seed (so each axis sees the same starts as the original, perturbed).
The table then holds, per suite, Acc_ori, Acc and gap = Acc_ori - Acc per LIBERO-PRO axis and PRO, the
mean over those axes; the language probes are reported beside them, outside PRO. The total row is the
mean over suites (every suite has as many tasks and episodes), as LIBERO-PRO's leaderboard reports.

Axes and what they run (`RobustnessConfig`): object (generated colours, textures and sizes, or LIBERO-PRO's
object swap), position (objects moved 0.2-0.3 m, or its position swap), semantic (paraphrase, or its
paraphrases), task (its target swap: a new goal, so a policy must read the instruction), env (the task moved
into another of LIBERO's scenes), and the probes (instruction shuffled, unrelated or empty: the task is
unchanged, only the words are not).

Layout of OUT::

    config.json               the suites, axes, variants and evaluation settings; a resumed run must match
                              them, except the episodes per task (more extend every axis's run)
    <suite>/<axis>/           `evaluate` run (axis "ori": no perturbation)
    robustness.json           per suite and in total: the metrics from success and from ESR
    report.md, robustness.png
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from annotations.format import task_key
from base_suites import UserInputError, task_specs
from base_suites.perturbations import BuildPlan, parse_perturbations
from base_suites.runtime.compute import ComputeConfig, use_compute
from base_suites.runtime.io import atomic_write_json, changed_fields, read_json_file
from base_suites.runtime.jobs import Workers, check_workers
from base_suites.runtime.locks import output_lock
from base_suites.runtime.outputs import check_output
from elegant.evaluation.config import PRO_AXES, PROBE_AXES, EvalConfig, RobustnessConfig
from elegant.evaluation.metrics import robustness_metrics
from elegant.evaluation.runner import build_agent, evaluate
from elegant.policies.specs import describe_policy
from elegant.reporting.html import write_report
from elegant.reporting.report import markdown_table, percent, save_figure

ROBUSTNESS_FORMAT = "libero-elegant-robustness/1"
# (table name, a run summary's rate and its 95% interval, title)
SOURCES = (
    ("success", "success_rate", "success_ci95", "success"),
    ("elegant", "esr", "esr_ci95", "elegant success (ESR)"),
)


def _variant_tasks(suite: str, tasks: Sequence[int | str] | None, spec: str) -> list[str]:
    """The task keys the runs of one axis play: the suite's own, or the LIBERO-PRO variant's (one line if
    the suite ships none)."""
    keys = []
    for task in task_specs(suite, tasks):
        plan = BuildPlan(task, task.language)
        for operator in parse_perturbations(spec):
            plan = operator.plan(plan)
        keys.append(task_key(plan.task.suite, plan.task.index))
    return keys


def _model_tasks(spec: Any) -> list[str] | None:
    """The tasks a policy or critic directory was trained on (None: a model that reads any task)."""
    if not isinstance(spec, (str, os.PathLike)) or not os.path.isdir(spec):
        return None
    from critics.artifact import CONFIG_FILE as CRITIC_CONFIG
    from elegant.policies.bc_artifact import CONFIG_FILE

    names = [n for n in (CONFIG_FILE, CRITIC_CONFIG) if os.path.isfile(os.path.join(spec, n))]
    config = read_json_file(os.path.join(spec, names[0] if names else CONFIG_FILE), "model config")
    encoder = config.get("features", {}).get("encoder") or config.get("encoder")
    return None if encoder is None or "layouts" not in encoder else sorted(encoder["layouts"])


def _refuse_unreadable_axes(policy: Any, critic: Any, plan: dict[str, dict[str, list[str]]]) -> None:
    """Before any run: a model trained on some tasks cannot play another task's variant (its input is that
    task's own state layout and one-hot); name the first axis it cannot run and how to leave it out."""
    models = [(policy, _model_tasks(policy))]
    if critic is not None:
        models += [(path, _model_tasks(path)) for path in str(critic).split(",")]
    for spec, known in models:
        if known is None:
            continue
        for suite, axes in plan.items():
            for axis, keys in axes.items():
                missing = [k for k in keys if k not in known]
                if missing:
                    others = [a for a in axes if a != "ori" and a != axis]
                    raise UserInputError(
                        f"{spec}: trained on {', '.join(known[:3])}{'...' if len(known) > 3 else ''}; the {axis} "
                        f"axis of {suite} plays {missing[0]}, which it cannot read; leave the axis out "
                        f"(--axes {','.join(others) or '...'}) or use a model of that task"
                    )


def _table(runs: dict[str, dict[str, dict[str, Any]]]) -> dict[str, Any]:
    """LIBERO-PRO's numbers per suite and in total, once from success and once from ESR; per suite also
    each run's 95% interval over starts (`ci95`, as its summary gives it; none for the total)."""
    table: dict[str, Any] = {}
    for name, key, interval, _ in SOURCES:
        rates = {suite: {axis: float(s[key]) for axis, s in axes.items()} for suite, axes in runs.items()}
        mean = {axis: float(np.mean([r[axis] for r in rates.values()])) for axis in next(iter(rates.values()))}
        rows = {**rates, "total": mean}
        table[name] = {}
        for suite, r in rows.items():
            pro_axes = {a: v for a, v in r.items() if a in PRO_AXES}
            metrics = robustness_metrics({"ori": r["ori"], **pro_axes}) if pro_axes else {"acc_ori": r["ori"]}
            probes = {a: {"acc": v, "gap": r["ori"] - v} for a, v in r.items() if a not in PRO_AXES and a != "ori"}
            table[name][suite] = {**metrics, "probes": probes}
            if suite in runs:
                table[name][suite]["ci95"] = {a: list(s[interval]) for a, s in runs[suite].items() if interval in s}
    return table


def run_robustness(
    suites: Sequence[str],
    policy: Any,
    critic: Any = None,
    out: str | os.PathLike = "runs/robustness",
    config: RobustnessConfig | None = None,
    eval_config: EvalConfig | None = None,
    *,
    tasks: Sequence[int | str] | None = None,
    resume: bool = False,
    workers: int | Workers = 1,
    compute: ComputeConfig | None = None,
    progress: bool = True,
    **settings: Any,
) -> dict[str, Any]:
    """Run the original tasks and every axis of `config` (default: all five LIBERO-PRO axes and the three
    probes) for each suite and write LIBERO-PRO's table (module docstring). The evaluation settings are
    `eval_config`'s with keyword `settings` (EvalConfig and JITIConfig fields) overriding them, except the
    perturbation, which each axis sets. `tasks`: indices within every suite (default: all). Returns the
    content of OUT/robustness.json."""
    config = config or RobustnessConfig()
    if "perturbation" in settings or (eval_config is not None and eval_config.perturbation):
        raise UserInputError("robustness: each axis sets its own perturbation; run `elegant eval` for one of your own")
    cfg = (eval_config or EvalConfig()).with_settings(**settings)
    if not suites or len(set(suites)) != len(suites):
        raise UserInputError(f"robustness: expected distinct suites, got {list(suites)}")
    device = use_compute(compute or ComputeConfig(), "robustness")
    workers = check_workers(workers)
    specs = config.perturbations()
    plan = {suite: {axis: _variant_tasks(suite, tasks, spec) for axis, spec in specs.items()} for suite in suites}
    _refuse_unreadable_axes(policy, critic, plan)
    build_agent(policy, critic, cfg, str(device))  # before any run: a mode without its critic, an unreadable model
    out = Path(out)
    record = {
        "format": ROBUSTNESS_FORMAT,
        "suites": list(suites),
        "tasks": None if tasks is None else [int(t) for t in tasks],
        "axes": specs,
        "policy": describe_policy(policy),
        "critic": None if critic is None else ",".join(os.path.abspath(p) for p in str(critic).split(",")),
        "evaluation": asdict(cfg),
    }
    check_output(str(out), "dir", resume=resume, results=("config.json",))
    with output_lock(out):
        if resume and (out / "config.json").exists():
            stored = read_json_file(out / "config.json", "robustness config")
            changed = [c for c in changed_fields(stored, record) if c[0] != "evaluation.episodes"]
            if changed:
                key, before, now = changed[0]
                raise UserInputError(
                    f"{out / 'config.json'}: field {key!r} is {before!r} but this run has {now!r}; resume only "
                    "with the same settings (only episodes may change)"
                )
        created = not out.exists()
        fresh = not (out / "config.json").exists()
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(out / "config.json", record)
        try:
            runs = _run_cells(suites, specs, out, tasks, policy, critic, cfg, workers, compute, progress)
        except UserInputError:
            if fresh:  # refused before its first episode (e.g. init states a suite lacks): leave nothing
                _remove_refused_run(out, created, [out / suite / axis for suite in suites for axis in specs])
            raise
        result = {"config": record, "runs": {s: {a: str(out / s / a) for a in specs} for s in suites}, **_table(runs)}
        atomic_write_json(out / "robustness.json", result)
        _plot(result, out / "robustness.png")
        write_report(out / "report.md", _markdown(result))
        return result


def _run_cells(
    suites: Sequence[str],
    specs: dict[str, str],
    out: Path,
    tasks: Sequence[int | str] | None,
    policy: Any,
    critic: Any,
    cfg: EvalConfig,
    workers: Workers,
    compute: ComputeConfig | None,
    progress: bool,
) -> dict[str, dict[str, dict[str, Any]]]:
    """Each suite's original and axis runs (`evaluate`, resumed where OUT holds them); their summaries."""
    runs: dict[str, dict[str, dict[str, Any]]] = {}
    cells = [(suite, axis) for suite in suites for axis in specs]
    for suite, axis in tqdm(cells, desc="robustness", unit="run", disable=not progress):
        run_dir = out / suite / axis
        summary_path = run_dir / "summary.json"
        summary = read_json_file(summary_path, "evaluation summary") if summary_path.exists() else None
        if summary is None or summary["config"]["episodes"] != cfg.episodes:  # new, or resumed with more
            summary = evaluate(
                suite,
                tasks,
                policy,
                critic,
                cfg.with_settings(perturbation=specs[axis] or None),
                out=run_dir,
                resume=True,
                workers=workers,
                compute=compute,
                progress=progress,  # the run's episodes under the bar of runs
            )
        runs.setdefault(suite, {})[axis] = summary
    return runs


def _remove_refused_run(out: Path, created: bool, run_dirs: Sequence[Path]) -> None:
    """What a fresh run wrote before its first run refused: its config and the empty directories of its
    runs (`evaluate` removes what a refused run wrote inside them); nothing else, and nothing at all once
    an episode finished, so that the corrected command can use the same directory."""
    if any((d / "episodes.jsonl").exists() for d in run_dirs):
        return
    (out / "config.json").unlink(missing_ok=True)
    for directory in [*run_dirs, *dict.fromkeys(d.parent for d in run_dirs), *([out] if created else [])]:
        if directory.is_dir() and not directory.is_symlink() and not any(directory.iterdir()):
            directory.rmdir()


def _cells(entry: dict[str, Any], axes: Sequence[str]) -> list[str]:
    cells = [percent(entry["acc_ori"])]
    for axis in axes:
        if axis in PRO_AXES:
            cells.append(f"{percent(entry['acc'][axis])} ({100 * entry['gap'][axis]:+.1f})")
        else:
            probe = entry["probes"][axis]
            cells.append(f"{percent(probe['acc'])} ({100 * probe['gap']:+.1f})")
    return [*cells, percent(entry["pro"]) if "pro" in entry else "—"]


def _markdown(result: dict[str, Any]) -> str:
    cfg = result["config"]
    axes = _ordered_axes(cfg)[1:]
    evaluation = cfg["evaluation"]
    lines = [
        "# LIBERO-PRO robustness: success and elegant success",
        "",
        f"- policy {cfg['policy']}; critic {cfg['critic'] or 'none'}; mode {evaluation['jiti']['mode']}",
        f"- {evaluation['episodes']} episodes per task and axis, seed {evaluation['seed']}; tasks "
        f"{'all' if cfg['tasks'] is None else ', '.join(map(str, cfg['tasks']))}",
        "- axes: " + ", ".join(f"{a} ({cfg['axes'][a]})" for a in axes),
        "",
        "Each cell: Acc on the axis (gap to the original in points; a positive gap is a drop). PRO: mean Acc over "
        "the LIBERO-PRO axes run; the probes (the instruction corrupted, the task unchanged) stay outside it. "
        "total: the mean over suites.",
    ]
    for name, _, _, title in SOURCES:
        rows = [[suite, *_cells(entry, axes)] for suite, entry in result[name].items()]
        lines += ["", f"## From {title}", "", markdown_table(["suite", "ori", *axes, "PRO"], rows)]
    lines += ["", "![robustness](robustness.png)"]
    return "\n".join(lines) + "\n"


def _plot(result: dict[str, Any], path: Path) -> Path:
    """Grouped bars: per suite (and the total, when there are several suites), Acc on the original and on
    each axis with its 95% interval over starts; success and ESR; one legend, below the panels."""
    from matplotlib.figure import Figure

    axes = _ordered_axes(result["config"])
    fig = Figure(figsize=(12, 4.4), layout="constrained")
    panels = fig.subplots(1, 2, sharey=True)
    for ax, (name, _, _, title) in zip(panels, SOURCES):
        rows = {s: e for s, e in result[name].items() if s != "total" or len(result[name]) > 2}
        width = 0.8 / len(axes)
        for i, axis in enumerate(axes):
            values = np.array([_acc(entry, axis) for entry in rows.values()])
            bounds = np.array([entry.get("ci95", {}).get(axis, (v, v)) for entry, v in zip(rows.values(), values)])
            errors = np.abs(bounds.T - values)
            x = np.arange(len(rows)) + (i - (len(axes) - 1) / 2) * width
            ax.bar(x, values, width, yerr=errors, capsize=2, error_kw={"elinewidth": 0.8}, label=axis)
        ax.set_xticks(range(len(rows)), list(rows))
        ax.set_ylim(0, 1.05)
        ax.set_title(f"Acc from {title}; bars: 95% interval over starts", fontsize=10)
    panels[0].set_ylabel("Acc (fraction of episodes)")
    handles, labels = panels[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=len(axes), fontsize=8)
    return save_figure(fig, path)


def _ordered_axes(config: dict[str, Any]) -> list[str]:
    """The run's axes in LIBERO-PRO's order, "ori" first and the probes last (a JSON record sorts its keys)."""
    return [a for a in ("ori", *PRO_AXES, *PROBE_AXES) if a in config["axes"]]


def _acc(entry: dict[str, Any], axis: str) -> float:
    if axis == "ori":
        return entry["acc_ori"]
    return entry["acc"][axis] if axis in PRO_AXES else entry["probes"][axis]["acc"]
