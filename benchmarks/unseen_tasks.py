"""JITI with goal-relative critics on tasks they never saw (docs/design.md §4.4), from one command.

Runs (or resumes) the chain of benchmarks/jiti_effect.py in --out: demos, the policy trained on every
task, its branch rollouts from starts 0-24, the task-onehot critics and their runs. Then, in OUT/unseen/:
1. the chain's annotated demos and rollouts, annotated again where they predate goal geometry;
2. `critic_members` goal-relative critics trained on the SEEN tasks' demos and rollouts only, with the
   chain's critic recipe;
3. base and JITI (the recipe's settings, no gate: a gate is chosen on a task's own runs) on the held-out
   starts of the UNSEEN tasks and of the SEEN tasks, paired per start;
4. the critics' AUROC on the rollouts of each group (held out for the unseen tasks, training data for the
   seen ones; `critics.evaluate_critic`, the members' mean).
With --gate, also JITI gated per unseen task (`elegant gate`, docs/design.md §7.8) from base and JITI
validation runs on that task's rollout starts: the critics still learn nothing from the task, the gate
spends validation episodes on it. With --compare-encodings, also goal-relative critics on every task
against the chain's task-onehot critics, both with ungated JITI on every task: what the task-agnostic
encoding costs on seen tasks.

    python benchmarks/unseen_tasks.py --out runs/effect --suites libero_object --seen 0-4 --unseen 5-9
        [--gate] [--compare-encodings] [--workers 2] [every chain option of jiti_effect.py]

Targets: on the unseen tasks JITI's ESR at least 10 points above base with success not lower; on every
task the goal-relative critics at most 3 ESR points below the task one-hot. Last line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
from dataclasses import replace

from chain_arguments import add_chain_arguments, chain_config

from annotations import DemoFile, annotate_file, task_key
from base_suites.runtime.jobs import workers_from_args
from base_suites.runtime.settings import index_list
from critics import evaluate_critic, train_critic
from elegant.evaluation.runner import evaluate
from elegant.intervention.gate import write_gate
from elegant.pipeline import chain_effects, init_split, run_chain

TARGETS = {"unseen_esr_gain": 0.10, "unseen_success_drop": 0.0, "encoding_esr_cost": 0.03}


def with_goal_geometry(path: str, folder: str, workers: int) -> str:
    """`path`, or where it is annotated again with goal geometry when its demos predate it."""
    with DemoFile(path) as f:
        if f.demo(f.names[0]).attrs.get("goal_geometry"):
            return path
    again = os.path.join(folder, os.path.basename(path))
    if not os.path.exists(again):
        annotate_file(path, again, resume=True, workers=workers)
    return again


def train_members(cfg, data: list[str], out: str, tasks: list[str] | None) -> str:
    """The chain's critic members, goal-relative, on `tasks` (None: all): their comma-joined directories."""
    dirs = []
    for k in range(cfg.critic_members):
        training = replace(
            cfg.critic_config(k), encoding="goal-relative", tasks=None if tasks is None else tuple(tasks)
        )
        directory = os.path.join(out, f"critic_{k + 1}")
        if not os.path.exists(os.path.join(directory, "critic.json")):
            train_critic(data, directory, training, resume=True)
        dirs.append(directory)
    return ",".join(dirs)


def paired(
    cfg, suite: str, tasks: list[int] | None, policy: str, critic: str, out: str, workers: int, base: tuple
) -> dict:
    """Base (`base`: its run directory and the critic it logs Q with, evaluated here if absent) and ungated
    JITI with `critic` in `out`, on `tasks`' held-out starts."""
    starts = init_split(cfg)[1]
    runs = {"base": base[0], "jiti": out}
    for mode, run in runs.items():
        evaluate(
            suite,
            tasks,
            policy,
            base[1] if mode == "base" else critic,
            cfg.eval_config(mode, starts),
            out=run,
            resume=True,
            workers=workers,
        )
    return chain_effects(runs)


def gated_run(cfg, suite: str, tasks: list[int], policy: str, critic: str, folder: str, workers: int) -> str:
    """JITI gated per task on the held-out starts, from base and JITI validation runs on the tasks' rollout
    starts with the same critics; the gated run's directory (in `folder`, as are the validation runs)."""
    rollout_starts, eval_starts = init_split(cfg)
    validation = {mode: os.path.join(folder, f"validate_{mode}_unseen") for mode in ("base", "jiti")}
    for mode, run in validation.items():
        evaluate(
            suite, tasks, policy, critic, cfg.eval_config(mode, rollout_starts), out=run, resume=True, workers=workers
        )
    gate = os.path.join(folder, "gate_unseen.json")
    write_gate(validation["base"], validation["jiti"], gate, overwrite=True)  # the same file on every resume
    run = os.path.join(folder, "jiti_unseen_gated")
    evaluate(
        suite, tasks, policy, critic, cfg.eval_config("jiti", eval_starts, gate), out=run, resume=True, workers=workers
    )
    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    add_chain_arguments(parser, recipe="effect")
    parser.add_argument("--seen", type=index_list, default=(0, 1, 2, 3, 4), help="task indices the critics learn from")
    parser.add_argument("--unseen", type=index_list, default=(5, 6, 7, 8, 9), help="task indices they never see")
    parser.add_argument("--gate", action="store_true", help="also JITI gated per unseen task from validation runs")
    parser.add_argument(
        "--compare-encodings", action="store_true", help="also goal-relative against task-onehot critics on every task"
    )
    args = parser.parse_args()
    if set(args.seen) & set(args.unseen):
        parser.error(f"--seen and --unseen share tasks {sorted(set(args.seen) & set(args.unseen))}")
    config = chain_config(args)
    if config.tasks is not None and not set(args.seen) | set(args.unseen) <= set(config.tasks):
        parser.error("--seen and --unseen must be among the chain's --tasks")
    workers = workers_from_args(args)
    chain = run_chain(args.out, config, workers=workers)
    policy = os.path.join(args.out, "policy")
    results = {}
    for suite in config.suites:
        folder = os.path.join(args.out, "unseen", suite)
        os.makedirs(folder, exist_ok=True)
        data = [
            with_goal_geometry(os.path.join(args.out, f"{name}_{suite}.hdf5"), folder, workers)
            for name in ("annotated", "annotated_rollouts")
        ]
        seen_keys = [task_key(suite, t) for t in args.seen]
        critic = train_members(config, data, os.path.join(folder, "seen_critics"), seen_keys)
        row = {}
        for group, tasks in (("unseen", list(args.unseen)), ("seen", list(args.seen))):
            effects = paired(
                config,
                suite,
                tasks,
                policy,
                critic,
                os.path.join(folder, f"jiti_{group}"),
                workers,
                (os.path.join(folder, f"base_{group}"), None),
            )
            keys = [task_key(suite, t) for t in tasks]
            aurocs = [evaluate_critic(member, data[1:], keys)["auroc"] for member in critic.split(",")]
            mean = None if None in aurocs else sum(aurocs) / len(aurocs)  # the members' mean
            row[group] = {"modes": effects, "auroc": mean}
        if args.gate:
            gated = gated_run(config, suite, list(args.unseen), policy, critic, folder, workers)
            row["unseen_gated"] = {"modes": chain_effects({"base": os.path.join(folder, "base_unseen"), "jiti": gated})}
        if args.compare_encodings:
            every = train_members(config, data, os.path.join(folder, "all_critics"), None)
            compared = {}
            onehot = _chain_critics(args.out, config)
            base = (chain["runs"]["base"][suite], onehot)  # the chain's base run, which logs its critics' Q
            every_task = None if config.tasks is None else list(config.tasks)
            for name, critics in (("task-onehot", onehot), ("goal-relative", every)):
                run = os.path.join(folder, f"jiti_all_{name}")
                compared[name] = paired(config, suite, every_task, policy, critics, run, workers, base)
            row["encodings"] = compared
        results[suite] = row
    print_table(results)
    verdicts = {suite: _verdicts(row) for suite, row in results.items()}
    record = {"benchmark": "unseen_tasks", "config": vars(args), "per_suite": results, "verdicts": verdicts}
    print(json.dumps({**record, "targets": TARGETS}))


def _verdicts(row: dict) -> dict:
    unseen = row["unseen"]["modes"]
    out = {
        "unseen_esr_gain": unseen["jiti"]["esr"] - unseen["base"]["esr"],
        "unseen_success_change": unseen["jiti"]["success_rate"] - unseen["base"]["success_rate"],
    }
    if "unseen_gated" in row:
        gated = row["unseen_gated"]["modes"]
        out["unseen_gated_esr_gain"] = gated["jiti"]["esr"] - gated["base"]["esr"]
        out["unseen_gated_success_change"] = gated["jiti"]["success_rate"] - gated["base"]["success_rate"]
    if "encodings" in row:
        by = row["encodings"]
        out["encoding_esr_cost"] = by["task-onehot"]["jiti"]["esr"] - by["goal-relative"]["jiti"]["esr"]
    return out


def print_table(results: dict) -> None:
    """Per suite and task group: base and JITI success and ESR, the pairing, the critics' AUROC."""
    print(f"{'suite':14s} {'tasks':17s} {'mode':5s} {'success':>8s} {'ESR':>6s} {'made/spoiled':>13s} {'p':>8s} AUROC")
    for suite, row in results.items():
        groups = [(g, row[g]["modes"], row[g]["auroc"]) for g in ("unseen", "seen")]
        groups += [("unseen+gate", row["unseen_gated"]["modes"], None)] if "unseen_gated" in row else []
        groups += [(f"all/{name}", modes, None) for name, modes in row.get("encodings", {}).items()]
        for group, modes, auroc in groups:
            for mode, r in modes.items():
                pair = f"{r['made_elegant']}/{r['spoiled']}" if "made_elegant" in r else ""
                p = f"{r['p_value']:.2g}" if "p_value" in r else ""
                shown = f"{auroc:.3f}" if auroc is not None and mode != "base" else ""
                rates = f"{r['success_rate']:8.1%} {r['esr']:6.1%}"
                print(f"{suite:14s} {group:17s} {mode:5s} {rates} {pair:>13s} {p:>8s} {shown}")


def _chain_critics(out: str, config) -> str:
    """The chain's own (task-onehot) critic members."""
    names = ["critic"] if config.critic_members == 1 else [f"critic_{k + 1}" for k in range(config.critic_members)]
    return ",".join(os.path.join(out, n) for n in names)


if __name__ == "__main__":
    main()
