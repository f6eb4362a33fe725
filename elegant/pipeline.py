"""The whole chain, resumable step by step: the quickstart and the effect benchmark are two sizes of it.

demos (scripted expert, mixed quality, per suite) -> annotate (ITC labels) -> train policy (BC, on every
suite's demos) -> [the policy's own exploring rollouts, annotated] -> train critic (Cal-QL, on every
suite's annotated demos and rollouts) -> evaluate each mode on identical starts, per suite -> side-by-side
report. Each step writes its output atomically and is
skipped when that output already exists, so an interrupted chain continues where it stopped; a chain
directory refuses to continue under other settings.
"""

from __future__ import annotations

import os
from typing import Any

from base_suites.runtime.compute import ComputeConfig, use_compute
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.jobs import Workers
from base_suites.runtime.locks import output_lock
from elegant.chain_config import ChainConfig, check_chain_settings, load_recipe
from elegant.chain_stages import ChainPaths, chain_stages, run_stages


def init_split(cfg: ChainConfig) -> tuple[list[int] | None, list[int] | None]:
    """(rollout starts, evaluation starts): the first and second half of the init states every chosen task
    has, when the critic learns from rollouts; (None, None), all starts for the evaluation, otherwise."""
    if not cfg.critic_rollouts:
        return None, None
    from base_suites import task_specs

    specs = [spec for suite in cfg.suites for spec in task_specs(suite, cfg.tasks)]
    shared = min(spec.n_init_states for spec in specs)
    if shared < 2:
        raise UserInputError(
            f"chain critic_rollouts: a task has {shared} init state, too few to keep rollout and evaluation starts "
            "apart"
        )
    return list(range(shared // 2)), list(range(shared // 2, shared))


def _pooled(summaries: list[dict[str, Any]]) -> dict[str, float]:
    """Success, ESR and interventions over several suites' runs, weighted by their episode counts."""
    n = sum(s["episodes"] for s in summaries)
    return {
        k: sum(s[k] * s["episodes"] for s in summaries) / n
        for k in ("success_rate", "esr", "interventions_per_episode")
    }


def run_chain(
    out: str,
    config: ChainConfig,
    progress: bool = True,
    workers: int | Workers = 1,
    compute: ComputeConfig | None = None,
) -> dict[str, Any]:
    """Run (or continue) the chain in directory `out`, its episodes (demos, annotation replays, rollouts,
    evaluations) on `workers` processes side by side: a run control, not a setting (the numbers do not
    depend on it), so a chain may be continued with another count. `compute`: where the policy and the
    critics train and score (`ComputeConfig`); its stages resume on the same kind of device only.

    Returns {mode: pooled success_rate, esr, interventions_per_episode}, per_suite {suite: {mode: the
    same}}, per_task {suite: {mode: the run summary's per-task rows}}, report (the path of the comparison
    markdown), runs ({mode: {suite: run directory}}), effects (`chain_effects` per suite). A second chain
    writing `out` at the same time is refused (`base_suites.runtime.locks`).
    """
    config.validate()  # bad settings are refused before the chain directory or its lock exists
    compute = compute or ComputeConfig()
    use_compute(compute, "chain")  # a device that is not there is refused before the first stage runs
    with output_lock(out):
        return _run_chain(out, config, progress, workers, compute)


def _run_chain(
    out: str, config: ChainConfig, progress: bool, workers: int | Workers, compute: ComputeConfig
) -> dict[str, Any]:
    """`run_chain`'s work, with the chain directory's lock held: its declared stages (`chain_stages`),
    then the comparison of every mode's runs."""
    from elegant.reporting.report import compare_runs

    cfg = config
    os.makedirs(out, exist_ok=True)
    check_chain_settings(out, cfg)
    paths = ChainPaths(out, cfg.suites, cfg.modes, cfg.critic_members)

    def say(step: str) -> None:
        if progress:
            print(f"[chain] {step}", flush=True)

    stages = chain_stages(paths, cfg, init_split(cfg), progress=progress, workers=workers, compute=compute)
    done = run_stages(stages, say)  # the evaluations always run (resuming), so each returns its summary
    runs = paths.runs
    summaries = {m: {s: done[f"eval {m} {s}"] for s in cfg.suites} for m in cfg.modes}
    report_dir = os.path.join(out, "report")
    compare_runs([runs[m][s] for s in cfg.suites for m in cfg.modes], report_dir)
    result: dict[str, Any] = {m: _pooled(list(summaries[m].values())) for m in cfg.modes}
    result["per_suite"] = {s: {m: _pooled([summaries[m][s]]) for m in cfg.modes} for s in cfg.suites}
    result["per_task"] = {s: {m: summaries[m][s]["per_task"] for m in cfg.modes} for s in cfg.suites}
    result["report"] = os.path.join(report_dir, "comparison.md")
    result["runs"] = runs
    result["effects"] = {suite: chain_effects({m: runs[m][suite] for m in cfg.modes}) for suite in cfg.suites}
    return result


def chain_effects(runs: dict[str, str]) -> dict[str, dict[str, Any]]:
    """Per mode of one suite's runs ({mode: run directory}): success and ESR with their intervals, starts,
    interventions per episode and their share of `always`'s, and against `base` the episodes made elegant /
    spoiled with the sign test over starts (`elegant.evaluation.metrics`)."""
    from elegant.evaluation.metrics import paired_comparison
    from elegant.reporting.report import load_run

    loaded = {mode: load_run(path) for mode, path in runs.items()}
    always = loaded["always"][0]["interventions_per_episode"] if "always" in loaded else None
    effects = {}
    for mode, (summary, records) in loaded.items():
        row: dict[str, Any] = {
            k: summary[k] for k in ("success_rate", "success_ci95", "esr", "esr_ci95", "starts", "episodes_per_start")
        }
        row["interventions_per_episode"] = summary["interventions_per_episode"]
        if always and mode not in ("always", "base"):
            row["share_of_always"] = summary["interventions_per_episode"] / always
        if "base" in loaded and mode != "base":
            paired = paired_comparison(loaded["base"][1], records, "elegant")
            row.update(made_elegant=paired["only_after"], spoiled=paired["only_before"], p_value=paired["p_value"])
        effects[mode] = row
    return effects


def effects_text(result: dict[str, Any]) -> str:
    """The human summary a chain ends with: per suite and mode, success and ESR with 95% intervals, what
    each mode did to elegance against the base policy, interventions, and where the report lies."""

    def rate(value: float, interval: list[float]) -> str:
        return f"{100 * value:.0f}% [{100 * interval[0]:.0f}-{100 * interval[1]:.0f}]"

    lines = []
    for suite, modes in result["effects"].items():
        first = next(iter(modes.values()))
        lines.append(f"{suite}: {first['starts']} starts, {first['episodes_per_start']:.3g} episode(s) each")
        for mode, row in modes.items():
            text = f"  {mode:7s} success {rate(row['success_rate'], row['success_ci95'])}, "
            text += f"ESR {rate(row['esr'], row['esr_ci95'])}"
            if "made_elegant" in row:
                text += f"; {row['made_elegant']} made elegant, {row['spoiled']} spoiled (p = {row['p_value']:.2g})"
            if mode != "base":
                text += f"; {row['interventions_per_episode']:.2f} interventions per episode"
            if "share_of_always" in row:
                text += f" ({100 * row['share_of_always']:.0f}% of always's)"
            lines.append(text)
    lines.append(f"report: {result['report']}")
    return "\n".join(lines)


def quickstart(
    out: str = "runs/quickstart",
    config: ChainConfig | None = None,
    progress: bool = True,
    workers: int | Workers = 1,
    compute: ComputeConfig | None = None,
) -> dict[str, Any]:
    """The README's first command: the chain with the recipe configs/quickstart.yaml (or `config`)."""
    return run_chain(out, config or load_recipe("quickstart"), progress=progress, workers=workers, compute=compute)
