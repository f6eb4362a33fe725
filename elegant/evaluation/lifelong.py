"""LIBERO's lifelong-learning protocol (Liu et al. 2023), reported from success and from elegant success.

K tasks of one suite are learned in order by ONE BC-GMM network, with one of LIBERO's algorithms
(`elegant.evaluation.lifelong_algos`): sequential fine-tuning (SeqL), experience replay (ER), elastic weight
consolidation (EWC) or PackNet; or by multitask training on all K tasks at once, LIBERO's upper bound.
The protocol around them follows LIBERO's `Sequential.learn_one_task` and `compute_metric`:

- The input covers all K tasks from the start: the task one-hot is over the K tasks, and each task's
  normalisation statistics are fitted on that task's demos (with `encoding="goal-relative"`: one set over
  all K tasks' demos, or a goal-relative pretrained policy's own). This needs every task's demos up front (the
  user passes all demo files at once), which is what LIBERO does too, as its data are all on disk; the
  statistics describe observation ranges only, nothing a later task's training learns.
- While learning task k, the network is evaluated on task k before any training on it (e = 0) and after
  every `eval_every` epochs: C[k, e] from success and C_elegant[k, e] from ESR.
- The network kept after task k is the first best of these checkpoints by success, as LIBERO keeps its
  best checkpoint ("as if it stopped learning there"; this is also why the metrics clamp C after its
  best point). The algorithm's end of task follows (EWC: Fisher information; PackNet: pruning and
  fine-tuning, whose best checkpoint is then kept). The next task starts from the kept network, and S
  uses it.
- After task k the kept network is evaluated on every task j <= k: S[k, j] and S_elegant[k, j] (PackNet:
  with task j's weights only). S[k, k] is the evaluation of the kept checkpoint on task k that already
  ran (episode starts depend only on the seed, and the policy acts deterministically), so it is read,
  not run again.
- Multitask: C[k, e] is task k's success at each evaluation epoch of the one training run; the first
  best checkpoint by mean success is kept, and its successes fill the last row of S only, as in LIBERO.
- FWT, NBT and AUC come from `elegant.evaluation.metrics.lifelong_metrics`, once on (S, C), once on the
  elegant pair, whose curves are clamped at the checkpoints kept by success (the ones S_elegant
  evaluates). `final_success` is the mean of S's last row: every task, once all are learned.

Layout of OUT (k is the position in the learning order, e an evaluation epoch)::

    config.json                    the run's settings; a resumed run must match them
    stages/task_<k>/               `train_policy` output of task k (checkpoint.pt, final policy) with
      epoch_<e>/                   the policy as of each evaluation epoch
      ewc_anchor.pt                EWC: Fisher information and weights after tasks 0..k
      pruned/, post/epoch_<e>/     PackNet: the pruned network (with packnet_masks.pt), its fine-tuning
      for_task_<j>/                PackNet: the network after task k with the weights of tasks 0..j only
    stages/all_tasks/epoch_<e>/    multitask: the one training run
    evals/task_<k>/epoch_<e>/      `evaluate` run of that snapshot on task k (C); PackNet adds post_epoch_<e>/
    evals/after_task_<k>/          `evaluate` run of the network kept after task k on tasks before it (S);
                                   PackNet: one run per earlier task, task_<j>/
    evals/all_tasks/epoch_<e>/     multitask: each snapshot on every task
    lifelong.json                  config, S, C, S_elegant, C_elegant, kept epochs, metrics, metrics_elegant
    report.md, success_matrix.png, learning_curves.png

Resuming (`resume=True`) skips finished stages and finished evaluations and continues a killed training
stage from its checkpoint, to the same numbers.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from annotations.format import task_key
from base_suites import get_task
from base_suites.runtime.compute import ComputeConfig, use_compute
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import atomic_write_json, changed_fields, read_json_file
from base_suites.runtime.jobs import Workers, check_workers
from base_suites.runtime.locks import output_lock
from base_suites.runtime.outputs import check_output
from base_suites.runtime.records import RecordFormat, fill_missing
from base_suites.runtime.settings import with_overrides
from elegant.evaluation.config import LifelongConfig
from elegant.evaluation.lifelong_algos import LifelongAlgorithm, lifelong_algorithm
from elegant.evaluation.lifelong_run import LifelongRun, stage_policy_config
from elegant.evaluation.metrics import clamp_learning_curves, lifelong_metrics
from elegant.policies.bc_artifact import read_artifact
from elegant.policies.bc_config import BCConfig
from elegant.policies.bc_data import DemoSet, load_demos
from elegant.policies.bc_features import BCFeatures
from elegant.policies.bc_train import FineTuning, network_spec, select_tasks, snapshot_dir
from elegant.reporting.html import write_report
from elegant.reporting.report import markdown_table, percent, save_figure

# the metrics a run reports, in LIBERO's order, and the mean success once every task is learned
METRIC_KEYS = ("fwt", "nbt", "auc", "final_success")


def _lifelong_from_v1(record: dict[str, Any]) -> dict[str, Any]:
    """A version-1 OUT/config.json as version 2. Version 1 records span the settings added since the
    first: before the mixture size was a setting, policies had 5 components; before the batch size was
    one, stages trained in batches of 256; before ER, EWC, PackNet and multitask, SeqL (then recorded as
    "sequential") had no settings of its own; before pre-training every run started from a fresh network;
    before the goal-relative encoding, stage policies read the task one-hot."""
    if record.get("algorithm") == "sequential":
        record["algorithm"] = "seql"
    return fill_missing(
        record, {"modes": 5, "batch_size": 256, "algorithm_settings": {}, "pretrained": None, "encoding": "task-onehot"}
    )


# OUT/config.json's format; records from before it had none and are version 1
LIFELONG_RECORD = RecordFormat("libero-elegant-lifelong", 2, {1: _lifelong_from_v1})


def _task_indices(suite: str, tasks: Sequence[int | str]) -> list[int]:
    """Suite indices of `tasks` in learning order, refusing an empty list, unknown tasks and repeats."""
    if not tasks:
        raise UserInputError("lifelong: expected at least one task")
    indices = [get_task(suite, t).index for t in tasks]
    repeated = sorted({i for i in indices if indices.count(i) > 1})
    if repeated:
        raise UserInputError(f"lifelong: task {repeated[0]} is listed more than once; each task is learned once")
    return indices


def _prepare(out: Path, config: dict[str, Any], resume: bool) -> None:
    """Never mix runs: a new run needs an empty OUT, a resumed one the settings of OUT/config.json."""
    path = out / "config.json"
    if resume and path.exists():
        recorded = LIFELONG_RECORD.upgrade(read_json_file(path, "lifelong config"), str(path))
        changed = changed_fields(recorded, config)
        if changed:
            key, before, now = changed[0]
            raise UserInputError(
                f"{path}: field {key!r} is {before!r} but this run has {now!r}; resume only with the same settings"
            )
    elif out.exists() and any(out.iterdir()):
        hint = "resume it (--resume)" if path.exists() else "it holds no lifelong run"
        raise UserInputError(f"{out}: not empty ({hint}); choose another directory")
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, config)


def lifelong_inputs(
    suite: str,
    tasks: Sequence[int | str],
    demo_paths: Sequence[str],
    cfg: LifelongConfig,
    pretrained: str | os.PathLike | None = None,
) -> tuple[dict[str, Any], DemoSet]:
    """The record of a run (OUT/config.json) and the demos of its tasks, refusing unknown or repeated tasks,
    demo files that lack a task's demos and a pretrained policy that cannot be read; writes nothing."""
    indices = _task_indices(suite, tasks)
    keys = [task_key(suite, i) for i in indices]
    if isinstance(demo_paths, (str, os.PathLike)) or not demo_paths:
        raise UserInputError("lifelong: expected a non-empty list of demo files")
    data = select_tasks(load_demos([os.fspath(p) for p in demo_paths]), keys)
    config = {
        "format": LIFELONG_RECORD.tag,
        "protocol": "LIBERO lifelong (Liu et al. 2023)",
        "algorithm": cfg.algo,
        "algorithm_settings": cfg.algorithm_settings(),
        "suite": suite,
        "tasks": indices,
        "task_keys": keys,
        "data": data.files,
        "epochs": int(cfg.epochs),
        "eval_every": int(cfg.eval_every),
        "eval_epochs": list(range(0, int(cfg.epochs) + 1, int(cfg.eval_every))),
        "episodes": int(cfg.episodes),
        "seed": int(cfg.seed),
        "max_steps": cfg.max_steps,
        "modes": int(cfg.modes),
        "batch_size": int(cfg.batch_size),
        "encoding": cfg.encoding,
        "pretrained": None,
    }
    if pretrained is not None:
        path = os.path.abspath(os.fspath(pretrained))
        _, features, artifact = read_artifact(path)
        if features.encoder.kind != cfg.encoding:
            raise UserInputError(
                f"{path}: the pretrained policy's input encoding is {features.encoder.kind} but this run has "
                f"{cfg.encoding} (--encoding {features.encoder.kind} to learn from it)"
            )
        if cfg.encoding == "goal-relative":
            _refuse_partial_transfer(path, features, artifact["model"], stage_policy_config(config), data)
        config["pretrained"] = {"path": path, "model_sha256": artifact["model_sha256"]}
    return config, data


def _refuse_partial_transfer(
    path: str, features: BCFeatures, model: dict[str, Any], policy: BCConfig, data: DemoSet
) -> None:
    """A goal-relative pretrained policy carries over whole: refuse one whose network or input differs
    from the stage policy's (e.g. trained with chunk 8), or that cannot read one of the run's demos."""
    if features.history != policy.history:
        raise UserInputError(
            f"{path}: input history is {features.history} states but lifelong stages read {policy.history}"
        )
    expected = network_spec(features, policy)
    for key in sorted(expected, key=lambda k: k != "chunk"):  # the chunk first: it also sets the head's width
        value = expected[key]
        if model.get(key) != value:
            raise UserInputError(
                f"{path}: model.{key} is {model.get(key)!r} but lifelong stage policies have {value!r} "
                "(train it with --chunk 1 and the stage's network)"
            )
    for episode in data.episodes:  # a goal the pretrained input cannot read is refused here, before OUT
        features.context_of(episode)


def _stage_features(config: dict[str, Any], data: DemoSet) -> BCFeatures:
    """The one input every stage policy reads: fitted over all K tasks' demos, or, from a goal-relative
    pretrained policy, that policy's own (its normalisation is what its weights learned, and a goal-relative
    input names no task, so every layer carries over; `lifelong_inputs` checked that it fits)."""
    pretrained = config.get("pretrained")
    if pretrained is not None and config["encoding"] == "goal-relative":
        return read_artifact(pretrained["path"])[1]
    policy = stage_policy_config(config)
    return BCFeatures.fit(data, history=policy.history, min_std=policy.obs_min_std, encoding=config["encoding"])


def _learn_and_measure(run: LifelongRun, algorithm: LifelongAlgorithm, k: int, C: np.ndarray, S: np.ndarray) -> int:
    """Stage k of the protocol: train (unless done), fill C[:, k] and S[:, k, :k+1]; returns the kept epoch.

    C and S hold success in [0] and ESR in [1].
    """
    cfg, keys = run.config, run.config["task_keys"]
    stage = run.stage_dir(k)
    if not os.path.exists(os.path.join(stage, "config.json")):  # train_policy publishes the final policy last
        run.status(f"{keys[k]}: training")
        algorithm.train_stage(run, k)
    for i, epoch in enumerate(cfg["eval_epochs"]):
        run.status(f"{keys[k]}: evaluating epoch {epoch}")
        C[:, k, i] = run.evaluate(snapshot_dir(stage, epoch), [k], run.out / "evals" / f"task_{k}" / f"epoch_{epoch}")[
            :, 0
        ]
    best = int(np.argmax(C[0, k]))  # the first best, as LIBERO replaces its checkpoint only on a strict gain
    kept, rates = algorithm.end_task(run, k, snapshot_dir(stage, cfg["eval_epochs"][best]))
    run.kept.append(kept)
    S[:, k, k] = C[:, k, best] if rates is None else rates
    if k:
        run.status(f"{keys[k]} learned: evaluating the {k} earlier task(s)")
        for policy, positions, run_dir in algorithm.earlier(run, k):
            S[:, k, positions] = run.evaluate(policy, positions, run_dir)
    return cfg["eval_epochs"][best]


def _learn_all_at_once(run: LifelongRun, C: np.ndarray, S: np.ndarray) -> list[int]:
    """Multitask training (LIBERO's upper bound): one network on all K tasks' demos, evaluated on every task
    before training and every `eval_every` epochs (C[:, k, e]); the first best checkpoint by mean success
    is kept, and its successes are the last row of S (the only row LIBERO's multitask fills)."""
    cfg, K = run.config, len(run.config["task_keys"])
    stage = str(run.out / "stages" / "all_tasks")
    if not os.path.exists(os.path.join(stage, "config.json")):
        run.status("all tasks: training")
        tune = FineTuning(tasks=cfg["task_keys"], snapshot_epochs=cfg["eval_epochs"], **run.fresh_start())
        run.train(stage, tune, cfg["epochs"], "all tasks")
    for i, epoch in enumerate(cfg["eval_epochs"]):
        run.status(f"all tasks: evaluating epoch {epoch}")
        C[:, :, i] = run.evaluate(
            snapshot_dir(stage, epoch), range(K), run.out / "evals" / "all_tasks" / f"epoch_{epoch}"
        )
    best = int(np.argmax(C[0].mean(axis=0)))
    run.kept.append(snapshot_dir(stage, cfg["eval_epochs"][best]))
    S[:, K - 1, :] = C[:, :, best]
    return [cfg["eval_epochs"][best]] * K


def _metrics(S: np.ndarray, C: np.ndarray, kept: list[int], multitask: bool) -> dict[str, Any]:
    """LIBERO's FWT, NBT and AUC of one (S, C) pair, plus `final_success`: the mean success on all tasks once
    all are learned (the last row of S). Multitask has no sequence: FWT is the area under its clamped
    curves (LIBERO's `learn_all_tasks`), NBT and AUC are None."""
    final = float(np.mean(S[-1]))
    if multitask:
        curves = clamp_learning_curves(C, kept)
        return {"fwt": float(curves.mean()), "nbt": None, "auc": None, "final_success": final}
    return {**lifelong_metrics(S, C, kept=kept), "final_success": final}


def run_lifelong(
    suite: str,
    tasks: Sequence[int | str],
    demo_paths: Sequence[str],
    out: str | os.PathLike,
    config: LifelongConfig | None = None,
    *,
    progress: bool = True,
    resume: bool = False,
    workers: int | Workers = 1,
    compute: ComputeConfig | None = None,
    pretrained: str | os.PathLike | None = None,
    **settings: Any,
) -> dict[str, Any]:
    """Learn `tasks` of `suite` in order with one of LIBERO's lifelong algorithms (`algo`: seql, er, ewc,
    packnet; multitask learns them all at once) and measure LIBERO's lifelong metrics.

    `demo_paths`: demo HDF5 files (from `elegant demos`) holding the demos of every task; task k learns
    from the demos with its task key. The settings are `config`'s (default: `LifelongConfig`'s), with
    keyword `settings` naming its fields overriding it: the algorithm and its own settings, epochs per
    task, evaluating the current task every `eval_every` epochs and before training on it, episodes per
    evaluation, seed, max_steps, the policy's mixture components. `workers`: processes running each
    evaluation's episodes (`elegant.evaluate`); `compute`: where the stages train and the evaluations
    score (`ComputeConfig`). `pretrained`: a policy directory (e.g. multitask-trained on libero_90) the first
    stage starts from, LIBERO-100's protocol: with the task one-hot its hidden layers and head carry over,
    while its input layer and task conditioning, made for other tasks' states, start fresh; with
    `encoding="goal-relative"` (the pretrained policy's too) the whole network and its input carry over.
    Writes OUT as the module docstring describes and returns the content of OUT/lifelong.json.
    """
    cfg = with_overrides(config or LifelongConfig(), settings, "lifelong")
    compute = compute or ComputeConfig()
    use_compute(compute, "lifelong")  # a device that is not there is refused before the first stage trains
    workers = check_workers(workers)
    config, data = lifelong_inputs(suite, tasks, demo_paths, cfg, pretrained)
    paths, keys = [os.fspath(p) for p in demo_paths], config["task_keys"]
    features = _stage_features(config, data)
    out = Path(out)
    algorithm = lifelong_algorithm(cfg.algo)
    multitask = not algorithm.staged
    check_output(str(out), "dir", resume=resume)  # an unwritable OUT is refused before its lock is made
    with output_lock(out):  # one writer per lifelong run directory
        _prepare(out, config, resume)
        K, E = len(keys), len(config["eval_epochs"])
        C = np.zeros((2, K, E))
        S = np.full((2, K, K), np.nan)
        with tqdm(total=1 if multitask else K, desc=f"lifelong {cfg.algo}", unit="stage", disable=not progress) as bar:
            settings = algorithm.read(config["algorithm_settings"])
            run = LifelongRun(out, config, paths, data, features, bar.set_postfix_str, workers, compute, settings)
            if multitask:
                kept_epochs = _learn_all_at_once(run, C, S)
                bar.update(1)
            else:
                kept_epochs = []
                for k in range(K):
                    kept_epochs.append(_learn_and_measure(run, algorithm, k, C, S))
                    bar.update(1)
        kept = [config["eval_epochs"].index(e) for e in kept_epochs]
        result = {
            "config": config,
            "kept_epochs": kept_epochs,
            "kept_policies": run.kept,
            "S": _matrix(S[0]),
            "C": C[0].tolist(),
            "S_elegant": _matrix(S[1]),
            "C_elegant": C[1].tolist(),
            "metrics": _metrics(S[0], C[0], kept, multitask),
            # Checkpoints are kept by success, so the elegant curves are clamped where those were kept.
            "metrics_elegant": _metrics(S[1], C[1], kept, multitask),
        }
        atomic_write_json(out / "lifelong.json", result)
        _write_report(out, result, S, C)
        return result


def _matrix(S: np.ndarray) -> list[list[float | None]]:
    """S as JSON: None where task j was not yet learned (i < j), since JSON has no NaN."""
    return [[None if np.isnan(v) else float(v) for v in row] for row in S]


# ---- report ----------------------------------------------------------------------------------------


def plot_success_matrices(S: np.ndarray, labels: list[str], path: Path) -> Path:
    """Heatmaps of S from success and from ESR; row i: after learning task i, column j: evaluated task."""
    from matplotlib.figure import Figure

    K = len(labels)
    fig = Figure(figsize=(3.0 + 2.2 * max(K, 2), 1.2 + 1.0 * max(K, 2)), layout="constrained")
    axes = fig.subplots(1, 2, sharey=True)
    for ax, matrix, title in zip(axes, S, ("success S", "elegant success S_elegant")):
        image = ax.imshow(np.ma.masked_invalid(matrix), vmin=0.0, vmax=1.0, cmap="viridis")
        for i, j in zip(*np.nonzero(~np.isnan(matrix))):
            ax.text(
                j,
                i,
                f"{matrix[i, j]:.2f}",
                ha="center",
                va="center",
                fontsize=8,
                color="w" if matrix[i, j] < 0.6 else "k",
            )
        ax.set_xticks(range(K), labels, rotation=30, ha="right", fontsize=7)
        ax.set_xlabel("evaluated task j")
        ax.set_title(title, fontsize=10)
    axes[0].set_yticks(range(K), labels, fontsize=7)
    axes[0].set_ylabel("after learning task i")
    fig.colorbar(image, ax=list(axes), shrink=0.8)
    return save_figure(fig, path)


def _plot_curves(C: np.ndarray, epochs: list[int], kept: list[int], labels: list[str], path: Path) -> Path:
    """Success and ESR of each task while learning it, against the epoch; a star marks the kept checkpoint."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 3.6), layout="constrained")
    for ax, curves, title in zip(
        fig.subplots(1, 2), C, ("success C (star: kept checkpoint)", "elegant success C_elegant")
    ):
        for k, label in enumerate(labels):
            (line,) = ax.plot(epochs, curves[k], marker="o", ms=3, lw=1.2, label=label)
            ax.plot([kept[k]], [curves[k][epochs.index(kept[k])]], marker="*", ms=10, color=line.get_color())
        ax.set_ylim(-0.05, 1.05)
        ax.set_xlabel("epoch of training on the task")
        ax.set_ylabel("rate")
        ax.set_title(title, fontsize=10)
        ax.legend(fontsize=7, loc="best")
    return save_figure(fig, path)


def _input_line(cfg: dict[str, Any]) -> str:
    """How the stage policies read a state (report line): the encoding, its normalisation, the pre-training."""
    pretrained = cfg["pretrained"]
    if cfg["encoding"] == "task-onehot":
        line = "task one-hot over the run's tasks, each task's normalisation fitted on its own demos"
        return line + ("" if pretrained is None else f"; hidden layers and head from {pretrained['path']}")
    if pretrained is None:
        return "goal-relative, one normalisation fitted on all the run's demos"
    return f"goal-relative, the whole network and its normalisation from {pretrained['path']}"


def _write_report(out: Path, result: dict[str, Any], S: np.ndarray, C: np.ndarray) -> None:
    """report.md with the metrics, S and C as tables (success / ESR), and the two plots."""
    cfg = result["config"]
    labels = [f"{k}: {key}" for k, key in enumerate(cfg["task_keys"])]
    plot_success_matrices(S, labels, out / "success_matrix.png")
    _plot_curves(C, cfg["eval_epochs"], result["kept_epochs"], labels, out / "learning_curves.png")

    def pair(s: float, e: float) -> str:
        return "—" if np.isnan(s) else f"{percent(s)} / {percent(e)}"

    metrics = [
        [name, *("—" if result[m][key] is None else f"{result[m][key]:.3f}" for key in METRIC_KEYS)]
        for name, m in (("success", "metrics"), ("elegant success (ESR)", "metrics_elegant"))
    ]
    lines = [
        f"# Lifelong learning: {cfg['suite']}, {lifelong_algorithm(cfg['algorithm']).title}",
        "",
        f"- tasks in learning order: {', '.join(labels)}",
        f"- {cfg['epochs']} epochs per task, evaluated at epochs {', '.join(map(str, cfg['eval_epochs']))}; "
        f"{cfg['episodes']} episodes per evaluation; seed {cfg['seed']}; max steps "
        f"{cfg['max_steps'] or 'suite default'}",
        f"- demos: {', '.join(f['path'] for f in cfg['data'])}; input: {_input_line(cfg)}",
        f"- algorithm settings: {json.dumps(cfg['algorithm_settings']) if cfg['algorithm_settings'] else 'none'}",
        "- kept checkpoint per task (first best success, as LIBERO): epoch "
        f"{', '.join(map(str, result['kept_epochs']))}",
        "",
        "## Metrics",
        "",
        markdown_table(["from", "FWT", "NBT", "AUC", "final"], metrics),
        "",
        "FWT: mean of the learning curves C (clamped at their best). NBT: mean drop of a task's success after "
        "later tasks were learned (lower is better). AUC: per task, learning curve and later successes together. "
        "final: mean over all tasks once all are learned (S's last row). Multitask has no sequence: no NBT, AUC.",
        "",
        "## Success matrix S: success / ESR on task j (column) after learning task i (row)",
        "",
        markdown_table(
            ["after \\ on", *labels],
            [[labels[i], *(pair(S[0, i, j], S[1, i, j]) for j in range(len(labels)))] for i in range(len(labels))],
        ),
        "",
        "![success matrix](success_matrix.png)",
        "",
        "## Learning curves C: success / ESR on the task being learned, per evaluation epoch",
        "",
        markdown_table(
            ["task", *(f"epoch {e}" for e in cfg["eval_epochs"])],
            [[labels[k], *(pair(C[0, k, i], C[1, k, i]) for i in range(C.shape[2]))] for k in range(len(labels))],
        ),
        "",
        "![learning curves](learning_curves.png)",
    ]
    write_report(out / "report.md", "\n".join(lines) + "\n")
