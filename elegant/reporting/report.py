"""Human-readable reports of evaluation runs: markdown tables and PNG plots (matplotlib, no display).

`write_run_report` turns one run directory into report.md, success_esr.png (success and ESR per task)
and q_trace.png (the critic's score of the base action along one episode, with the window mean, the
threshold band, the interventions and the violated ITC windows). `compare_runs` puts several runs side
by side (`elegant report RUN_A RUN_B ...`) and, where runs differ only in their perturbation, adds the
LIBERO-PRO robustness numbers. Figures are drawn on `matplotlib.figure.Figure` directly, so no global
pyplot state or GUI backend is involved; every file is written atomically.
"""

from __future__ import annotations

import io
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from annotations.format import CRITERIA, SEGMENT_LENGTH
from base_suites.perturbations import parse_perturbations
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import atomic_write
from base_suites.stack import check_same_stack
from elegant.evaluation.episode_log import EpisodeLog, run_records
from elegant.evaluation.metrics import paired_comparison, robustness_metrics, summarize
from elegant.evaluation.run_record import read_run_config
from elegant.intervention.modes import jiti_mode, mode_names
from elegant.reporting.html import write_report


def save_figure(fig, path: Path) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    atomic_write(path, buf.getvalue())
    return path


def percent(x: float) -> str:
    return "n/a" if x is None or np.isnan(x) else f"{100 * x:.1f}%"


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    lines = ["| " + " | ".join(map(str, header)) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(map(str, row)) + " |" for row in rows]
    return "\n".join(lines)


# ---- plots -----------------------------------------------------------------------------------------


def plot_bars(
    groups: Sequence[str],
    series: Mapping[str, Sequence[float]],
    title: str,
    path: Path,
    intervals: Mapping[str, Sequence[Sequence[float]]] | None = None,
) -> Path:
    """Grouped bars: one group per entry of `groups`, one bar per series (values are rates in [0, 1]), with
    `intervals[series][group]` = (low, high) drawn as error bars; the legend sits right of the axes, so it
    covers no bar."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(max(5.0, 0.9 * len(groups) * max(1, len(series)) ** 0.5 + 2) + 2.2, 3.6))
    ax = fig.add_subplot()
    width = 0.8 / max(1, len(series))
    x = np.arange(len(groups))
    for i, (name, values) in enumerate(series.items()):
        values = _floats(values)
        errors = None
        if intervals is not None and name in intervals:
            low, high = _floats([b[0] for b in intervals[name]]), _floats([b[1] for b in intervals[name]])
            errors = np.maximum(np.vstack([values - low, high - values]), 0.0)  # rounding at a rate of 0 or 1
        bars = ax.bar(x + (i - (len(series) - 1) / 2) * width, values, width, label=name, yerr=errors, capsize=2)
        ax.bar_label(bars, fmt="%.2f", fontsize=6, label_type="center")
    ax.set_xticks(x, groups, rotation=30, ha="right", fontsize=8)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("rate" + (" (95% interval over starts)" if intervals else ""))
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    fig.subplots_adjust(right=0.72)
    return save_figure(fig, path)


def _floats(values: Sequence[float | None]) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], dtype=np.float64)


def plot_q_trace(trace: Mapping[str, Any], path: Path) -> Path:
    """The Q trace of one episode: base action's score, window mean +- tau, interventions, violated windows."""
    from matplotlib.figure import Figure

    d = trace["decisions"]
    steps = np.asarray(d["step"])
    q, mean, tau, chosen_q = (_floats(d[k]) for k in ("q", "mean", "tau", "chosen_q"))
    fig = Figure(figsize=(11, 3.6))
    ax = fig.add_subplot()
    colours = dict(zip(CRITERIA, ("tab:purple", "tab:orange", "tab:green", "tab:brown")))
    for criterion, kept in trace.get("segments", {}).items():
        spans = [w for w, ok in enumerate(kept) if not ok]
        for n, w in enumerate(spans):  # one colour per criterion, in the legend once
            label = f"{criterion} violated" if n == 0 else None
            ax.axvspan(w * SEGMENT_LENGTH, (w + 1) * SEGMENT_LENGTH, color=colours.get(criterion), alpha=0.12, lw=0,
                       label=label)  # fmt: skip
    ax.plot(steps, q, lw=1.2, label="Q(s, base action)")
    if _uses_window(trace.get("mode")) and np.isfinite(mean).any():
        ax.plot(steps, mean, "--", lw=1, color="gray", label="window mean")
        ax.fill_between(steps, mean - tau, mean + tau, color="gray", alpha=0.15, lw=0, label="mean ± τ")
    hit = np.asarray(d["intervened"], dtype=bool)
    if hit.any():
        ax.scatter(
            steps[hit], chosen_q[hit], marker="v", s=18, color="tab:red", zorder=3, label="intervention (executed Q)"
        )
    ax.set_xlabel("step")
    ax.set_ylabel("Q: the critic's estimate of\nthe discounted elegance return", fontsize=8)
    violated = ", ".join(trace.get("violated", [])) or "none"
    ax.set_title(
        f"{trace['task']} episode {trace['episode']} ({trace['mode']}): success={trace['success']}, "
        f"elegant={trace['elegant']}, violated: {violated} (shaded windows)",
        fontsize=9,
    )
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    fig.subplots_adjust(right=0.8)
    return save_figure(fig, path)


# ---- one run ---------------------------------------------------------------------------------------


def _with_interval(rate: float, interval: Sequence[float]) -> str:
    return f"{percent(rate)} [{percent(interval[0])}, {percent(interval[1])}]"


def _summary_rows(s: Mapping[str, Any]) -> list[list[str]]:
    rows = [
        ["episodes", str(s["episodes"])],
        ["distinct starts (episodes per start)", f"{s['starts']} ({s['episodes_per_start']:.3g})"],
        ["success rate [95% interval]", _with_interval(s["success_rate"], s["success_ci95"])],
        ["ESR (elegant success rate) [95% interval]", _with_interval(s["esr"], s["esr_ci95"])],
    ]
    rows += [[f"violation rate: {c}", percent(v)] for c, v in s["itc_violation_rate"].items()]
    rows += [[f"succeeded, but violated: {c}", percent(v)] for c, v in s["success_with_violation"].items()]
    rows += [
        ["interventions / episode", f"{s['interventions_per_episode']:.2f}"],
        ["overrides / episode (executed action != base)", f"{s['overrides_per_episode']:.2f}"],
        ["steps / episode", f"{s['steps_per_episode']:.1f}"],
        ["decision time / step", f"{1e3 * s['decision_time']:.3f} ms"],
        ["env step time / step", f"{1e3 * s['env_step_time']:.2f} ms"],
        ["decision overhead", percent(s["decision_overhead"])],
    ]
    return rows


def _traced_episode(run_dir: Path, records: Sequence[Mapping[str, Any]]) -> dict[str, Any] | None:
    """The trace to plot: the episode with the most interventions (the first such), if it has Q values."""
    if not records:
        return None
    best = max(records, key=lambda r: r["interventions"])
    path = run_dir / best["trace"]
    if not path.exists():
        return None
    trace = json.loads(path.read_text())
    return trace if any(v is not None for v in trace["decisions"]["q"]) else None


def _uses_window(mode: str | None) -> bool:
    """Whether runs of `mode` measure fluctuations over a window (only those draw its mean and band)."""
    return mode in mode_names() and jiti_mode(mode).uses_window


def _settings_line(cfg: Mapping[str, Any]) -> str:
    """The settings that shaped a run of its mode, and only those (a base run used none of JITI's)."""
    jiti, mode = cfg["jiti"], jiti_mode(cfg["mode"])
    if not mode.settings:
        return mode.describe(jiti, "")
    source = cfg["candidate_source"]
    radius = jiti.get("trust_radius")
    candidates = f"N = {jiti['n_candidates']} candidates ({source}), trust radius {radius if radius else 'none'}"
    chunk = f", decisions every {jiti['chunk']} steps" if jiti["chunk"] > 1 else ""
    return mode.describe(jiti, candidates) + chunk


def write_run_report(
    run_dir: str | os.PathLike, summary: Mapping[str, Any], records: Sequence[Mapping[str, Any]]
) -> list[Path]:
    """Write report.md and its PNG plots into `run_dir`; returns the files written."""
    run_dir = Path(run_dir)
    cfg = read_run_config(summary["config"], str(run_dir))  # a run from before a setting reads as it ran
    per_task = summary["per_task"]
    tasks = list(per_task)
    files = [
        plot_bars(
            tasks,
            {"success": [per_task[t]["success_rate"] for t in tasks], "ESR": [per_task[t]["esr"] for t in tasks]},
            f"{cfg['suite']} — mode {cfg['mode']}",
            run_dir / "success_esr.png",
            {"success": [per_task[t]["success_ci95"] for t in tasks], "ESR": [per_task[t]["esr_ci95"] for t in tasks]},
        )
    ]
    trace = _traced_episode(run_dir, records)
    if trace is not None:
        files.append(plot_q_trace(trace, run_dir / "q_trace.png"))
    lines = [
        f"# Evaluation: {cfg['suite']}, mode `{cfg['mode']}`",
        "",
        f"- policy: `{cfg['policy']}` (policy act: {cfg['policy_act']})",
        f"- critic: `{cfg['critic']}`",
        f"- tasks: {', '.join(map(str, cfg['tasks']))}; episodes per task: {cfg['episodes']}; seed: {cfg['seed']}",
        f"- perturbation: {cfg['perturbation'] or 'none'}; max steps: {cfg['max_steps'] or 'suite default'}",
        f"- {_settings_line(cfg)}",
        "",
        "## Overall",
        "",
        markdown_table(["metric", "value"], _summary_rows(summary)),
        "",
        "Violation rate: fraction of episodes with at least one violated 25-step window of the criterion; "
        "'succeeded, but violated': the fraction that reached the goal with such a window, which is where "
        "the gap between success and ESR comes from. Intervals: Wilson score, 95%, with the start as the unit "
        "(repeated episodes of a start count by how much they differ; identical ones count once). "
        "Decision overhead: JITI's time per step over the env's step time.",
        "",
        "## Per task",
        "",
        markdown_table(
            ["task", "episodes", "success", "ESR", "interventions / ep", *CRITERIA],
            [
                [
                    t,
                    b["episodes"],
                    percent(b["success_rate"]),
                    percent(b["esr"]),
                    f"{b['interventions_per_episode']:.2f}",
                    *(percent(b["itc_violation_rate"][c]) for c in CRITERIA),
                ]
                for t, b in per_task.items()
            ],
        ),
        "",
        "![success and ESR per task](success_esr.png)",
    ]
    if trace is not None:
        lines += ["", f"## Q trace: {trace['task']}, episode {trace['episode']}", "", "![Q trace](q_trace.png)"]
    page = write_report(run_dir / "report.md", "\n".join(lines) + "\n")
    return [run_dir / "report.md", page, *files]


# ---- several runs ----------------------------------------------------------------------------------


def load_run(run_dir: str | os.PathLike) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """A finished run's summary and episode records. The metrics are recomputed from the records, so runs
    written before a metric existed compare with it too."""
    run_dir = Path(run_dir)
    path = run_dir / "summary.json"
    if not path.exists():
        raise UserInputError(f"{run_dir}: no summary.json; expected the directory of a finished `elegant eval` run")
    try:
        config = json.loads(path.read_text())["config"]
    except (json.JSONDecodeError, KeyError, TypeError):
        raise UserInputError(f"{path}: not the JSON summary of an `elegant eval` run (no field 'config')") from None
    config = read_run_config(config, str(path))
    records = run_records(EpisodeLog(run_dir / "episodes.jsonl").records, config)
    if not records:
        raise UserInputError(f"{run_dir / 'episodes.jsonl'}: no finished episodes")
    return {"config": config, **summarize(records)}, records


def _paired_rows(labels: Sequence[str], runs: Sequence[Sequence[Mapping[str, Any]]]) -> list[dict[str, Any]]:
    """Every later run against the first, episode by episode on their shared starts."""
    rows = []
    for label, records in zip(labels[1:], runs[1:]):
        rows.append({"run": label, **{key: paired_comparison(runs[0], records, key) for key in ("success", "elegant")}})
    return rows


def _paired_cell(p: Mapping[str, Any]) -> str:
    return (
        f"{100 * p['difference']:+.1f} points ({p['only_after']} gained, {p['only_before']} lost; "
        f"{p['starts_better']} of {p['starts']} starts better, {p['starts_worse']} worse, p = {p['p_value']:.3g})"
        if p["pairs"]
        else "no shared starts"
    )


def perturbation_axis(perturbation: str | None) -> str:
    """The robustness column a run's perturbation string belongs to: "ori" for none, "init+language" for two;
    an operator in a mode other than its generated default keeps the mode ("language@shipped" is LIBERO-PRO's
    semantic axis, "language@target_swap" its task axis, "init@nudge" fresh starts, not its position axis)."""
    if not perturbation:
        return "ori"
    return "+".join(p.robustness_axis for p in parse_perturbations(perturbation))


def _robustness(summaries: Sequence[Mapping[str, Any]], dirs: Sequence[Path]) -> dict[str, Any]:
    """LIBERO-PRO numbers for each group of runs that differ only in their perturbation; two runs for one
    cell are refused, naming both."""
    groups: dict[str, dict[str, Mapping[str, Any]]] = {}
    where: dict[tuple[str, str], Path] = {}
    for s, run_dir in zip(summaries, dirs):
        cfg = s["config"]
        key = json.dumps(
            [
                cfg["suite"],
                cfg["tasks"],
                cfg["policy"],
                cfg["critic"],
                cfg["mode"],
                cfg["policy_act"],
            ]
        )
        axis = perturbation_axis(cfg["perturbation"])
        if (key, axis) in where:
            raise UserInputError(
                f"report: runs {where[key, axis]} and {run_dir} are both the '{axis}' cell of one robustness "
                "table (same suite, tasks, policy, critic, mode and policy act); pass one of them"
            )
        where[key, axis] = run_dir
        groups.setdefault(key, {})[axis] = s
    out = {}
    for key, by_axis in groups.items():
        if "ori" in by_axis and len(by_axis) > 1:
            suite, _, policy, _, mode, _ = json.loads(key)
            name = f"{suite} / {mode} / {os.path.basename(str(policy))}"
            out[name] = {
                "success": robustness_metrics({a: s["success_rate"] for a, s in by_axis.items()}),
                "elegant": robustness_metrics({a: s["esr"] for a, s in by_axis.items()}),
            }
    return out


def compare_runs(
    run_dirs: Sequence[str | os.PathLike], out: str | os.PathLike | None = None, *, videos: int = 0
) -> dict[str, Any]:
    """Side-by-side comparison of finished runs (`elegant report RUN_A RUN_B ...`).

    Returns {"runs": [{label, dir, config}], "markdown": str, "paired": [...], "robustness": {...}, "files":
    [...]}; "paired" compares every later run with the first on their shared starts
    (`elegant.evaluation.metrics.paired_comparison` of success and of elegant success). With
    `out`, writes out/comparison.md and out/comparison.png (grouped bars of success and ESR per task);
    without it nothing is written. `videos` K > 0 (needs `out`) also replays up to K episodes per group
    and run (`elegant.reporting.videos`: made elegant, spoiled, inelegant successes) into out/videos/ and
    lists them ("clips").
    """
    if not run_dirs:
        raise UserInputError("report: expected at least one run directory")
    if videos < 0 or int(videos) != videos:
        raise UserInputError(f"report: --videos must be a whole number >= 0, got {videos!r}")
    if videos and out is None:
        raise UserInputError("report: --videos writes MP4s; give --out DIR for them")
    dirs = [Path(d) for d in run_dirs]
    summaries, records = zip(*(load_run(d) for d in dirs))
    check_same_stack([(str(d), s["config"].get("stack")) for d, s in zip(dirs, summaries)], "a report")
    names = [d.name or str(d) for d in dirs]
    if len(set(names)) < len(names):
        names = [str(d) for d in dirs]
    labels = [f"{n} ({s['config']['mode']})" for n, s in zip(names, summaries)]
    overall = [_summary_rows(s) for s in summaries]
    rows = [[overall[0][i][0], *(o[i][1] for o in overall)] for i in range(len(overall[0]))]
    tasks = list(dict.fromkeys(t for s in summaries for t in s["per_task"]))

    def cell(s: Mapping[str, Any], t: str) -> str:
        b = s["per_task"].get(t)
        return "—" if b is None else f"{percent(b['success_rate'])} / {percent(b['esr'])}"

    lines = [
        "# Run comparison",
        "",
        markdown_table(["metric", *labels], rows),
        "",
        "## Success / ESR per task",
        "",
        markdown_table(["task", *labels], [[t, *(cell(s, t) for s in summaries)] for t in tasks]),
    ]
    paired = _paired_rows(labels, records)
    if paired:
        lines += [
            "",
            f"## Paired with {labels[0]}",
            "",
            "Episodes of two runs with the same seed start alike; each cell counts the episodes where only one "
            "of the two runs succeeded (or succeeded elegantly), and the starts whose episodes did better or "
            "worse, with the exact sign test over starts (McNemar's test when every start runs once).",
            "",
            markdown_table(
                ["run", "episode pairs", "success", "ESR"],
                [
                    [p["run"], p["success"]["pairs"], _paired_cell(p["success"]), _paired_cell(p["elegant"])]
                    for p in paired
                ],
            ),
        ]
    robustness = _robustness(summaries, dirs)
    for name, r in robustness.items():
        axes = list(r["success"]["acc"])
        lines += [
            "",
            f"## Robustness (LIBERO-PRO): {name}",
            "",
            markdown_table(
                ["", "ori", *axes, "PRO (mean over axes)", "mean gap"],
                [
                    [
                        kind,
                        percent(r[kind]["acc_ori"]),
                        *(f"{percent(r[kind]['acc'][a])} (gap {percent(r[kind]['gap'][a])})" for a in axes),
                        percent(r[kind]["pro"]),
                        percent(r[kind]["mean_gap"]),
                    ]
                    for kind in ("success", "elegant")
                ],
            ),
        ]
    clips: list[dict[str, Any]] = []
    if videos:
        from elegant.reporting.videos import clips_markdown, write_clips

        clips = write_clips(dirs, labels, records, out, int(videos))
        lines += clips_markdown(clips)
    markdown = "\n".join(lines) + "\n"
    files: list[Path] = []
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        groups = tasks if len(tasks) == 1 else ["all", *tasks]  # with one task "all" would repeat it
        series, intervals = {}, {}
        for label, s in zip(labels, summaries):
            for metric, name in (("success_rate", "success"), ("esr", "ESR")):
                blocks = [s if g == "all" else s["per_task"].get(g, {}) for g in groups]
                series[f"{label} {name}"] = [b.get(metric, np.nan) for b in blocks]
                interval = "success_ci95" if metric == "success_rate" else "esr_ci95"
                intervals[f"{label} {name}"] = [b.get(interval, (np.nan, np.nan)) for b in blocks]
        files = [plot_bars(groups, series, "success and ESR per task", out / "comparison.png", intervals)]
        page = write_report(out / "comparison.md", markdown + "\n![success and ESR per task](comparison.png)\n")
        files[:0] = [out / "comparison.md", page]
    return {
        "runs": [
            {"label": label, "dir": str(d), "config": s["config"]} for label, d, s in zip(labels, dirs, summaries)
        ],
        "markdown": markdown,
        "paired": paired,
        "robustness": robustness,
        "files": [str(f) for f in files] + [os.path.join(out, c["path"]) for c in clips],
        "clips": clips,
    }
