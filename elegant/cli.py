"""The `elegant` command line: each subcommand parses its arguments and calls one library function.

Heavy imports (robosuite, LIBERO, torch) happen inside the command functions, so `elegant --help` is
instant. A user mistake (`UserInputError`) becomes one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import warnings
from collections.abc import Callable, Sequence
from typing import Any, NoReturn

COMMANDS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None], Callable[[argparse.Namespace], object]]] = {}


POLICY_HELP = (
    "a policy: a train-policy directory, module:factory[:JSON kwargs] (a Python entry point returning a "
    "policy), or ws://host:port / openpi://host:port (an openpi policy server; pip install -e .[openpi])"
)


def command(name: str, help_text: str):
    """Register a subcommand: the decorated function adds its arguments, `run` does the work."""

    def register(add_arguments):
        def bind(run):
            COMMANDS[name] = (help_text, add_arguments, run)
            return run

        return bind

    return register


def _print_json(result: object) -> None:
    """Print a command's result as strict JSON (NaN or infinity, an undefined rate, become null), a list of
    numbers on one line."""
    text = json.dumps(_strict(result), indent=2, default=str, allow_nan=False)
    print(re.sub(rf"\[\s*((?:{_SCALAR},\s*)*{_SCALAR})\s*\]", _one_line_list, text))


_SCALAR = r"(?:-?[\d.]+(?:[eE][-+]?\d+)?|null|true|false)"  # a number or literal: no string can hold a comma


def _one_line_list(match: re.Match) -> str:
    return "[" + ", ".join(item.strip() for item in match.group(1).split(",")) + "]"


def _strict(value: object) -> object:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _strict(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_strict(v) for v in value]
    return value


def _suites_args(p: argparse.ArgumentParser) -> None:
    pass


@command("suites", "list the LIBERO and LIBERO-PRO suites")(_suites_args)
def _suites(args: argparse.Namespace) -> None:
    from base_suites import list_suites, list_tasks

    for suite in list_suites():
        print(f"{suite:24s} {len(list_tasks(suite)):3d} tasks")


def _tasks_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("suite")


@command("tasks", "list a suite's tasks: index, instruction, goal, init states")(_tasks_args)
def _tasks(args: argparse.Namespace) -> None:
    from base_suites import list_tasks

    for t in list_tasks(args.suite):
        goal = " & ".join(f"{p[0]}({', '.join(p[1:])})" for p in t.goal)
        print(f"{t.index:3d}  {t.language}\n     goal: {goal}   init states: {t.n_init_states}")


def _tasks_arg(p: Any, help: str = "task indices, e.g. 0-4 or 0,3 (default: all of the suite)") -> None:
    """`--tasks` on a parser or an option group, read by the one index parser every generated option uses."""
    from base_suites.runtime.settings import index_list

    p.add_argument("--tasks", type=index_list, metavar="TASKS", help=help)


def _listed(indices: tuple[int, ...] | None) -> list[int] | None:
    return None if indices is None else list(indices)


def _workers_arg(p: argparse.ArgumentParser, default: int = 1) -> None:
    from base_suites.runtime.jobs import add_workers_argument  # light: no simulator, no torch

    add_workers_argument(p, default)


def _workers(args: argparse.Namespace) -> Any:
    """Where the command's episodes run: `--workers`, `--backend`, `--ray-address`."""
    from base_suites.runtime.jobs import workers_from_args

    return workers_from_args(args)


def _compute_args(p: argparse.ArgumentParser) -> None:
    """--device and --threads: where a command's networks train and score (`ComputeConfig`)."""
    from base_suites.runtime.compute import ComputeConfig
    from base_suites.runtime.settings import add_settings_arguments

    add_settings_arguments(p, ComputeConfig)


def _compute(args: argparse.Namespace) -> Any:
    """The `ComputeConfig` the options name (each command refuses a malformed one before any work)."""
    from base_suites.runtime.compute import ComputeConfig
    from base_suites.runtime.settings import settings_from_args

    return ComputeConfig(**settings_from_args(args, ComputeConfig))


def _overwrite_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--overwrite", action="store_true", help="replace an existing output (a file only once the new one is complete)"
    )


def _demos_args(p: argparse.ArgumentParser) -> None:
    from annotations.collect import DemoConfig
    from base_suites.runtime.settings import add_settings_arguments

    p.add_argument("--suite", required=True)
    _tasks_arg(p)
    p.add_argument("--out", required=True)
    p.add_argument("--resume", action="store_true", help="continue an interrupted file")
    _overwrite_arg(p)
    add_settings_arguments(p, DemoConfig)
    _workers_arg(p)


@command("demos", "roll out scripted experts and write a LIBERO-layout HDF5 demos file")(_demos_args)
def _demos(args: argparse.Namespace) -> dict:
    from annotations.collect import DemoConfig, collect_demos
    from base_suites.runtime.settings import config_from_args

    config = config_from_args(args, DemoConfig, "demos")
    return collect_demos(
        args.suite,
        _listed(args.tasks),
        args.out,
        config,
        resume=args.resume,
        overwrite=args.overwrite,
        workers=_workers(args),
    )


def _rollouts_args(p: argparse.ArgumentParser) -> None:
    from base_suites.runtime.settings import add_settings_arguments
    from elegant.evaluation.config import RolloutConfig

    p.add_argument("--suite", required=True)
    _tasks_arg(p)
    p.add_argument("--policy", required=True, help=POLICY_HELP)
    p.add_argument("--out", required=True, help="output HDF5 (demo layout; annotate it with elegant annotate)")
    p.add_argument("--resume", action="store_true", help="continue OUT.partial")
    _overwrite_arg(p)
    add_settings_arguments(p, RolloutConfig)
    _workers_arg(p)


@command(
    "rollouts",
    "record a policy's episodes (optionally exploring) as a demo-layout HDF5 for annotation and critic training",
)(_rollouts_args)
def _rollouts(args: argparse.Namespace) -> dict:
    from base_suites.runtime.settings import config_from_args
    from elegant.evaluation.config import RolloutConfig
    from elegant.evaluation.rollouts import collect_rollouts

    config = config_from_args(args, RolloutConfig, "rollouts")
    return collect_rollouts(
        args.suite,
        _listed(args.tasks),
        args.policy,
        args.out,
        config,
        resume=args.resume,
        overwrite=args.overwrite,
        workers=_workers(args),
    )


def _import_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help="a LIBERO HDF5 demonstration file")
    p.add_argument("--out", required=True)
    p.add_argument("--suite", help="suite of the task (default: found from the file's bddl_file_name)")
    p.add_argument("--task", type=int, help="task index (with --suite)")
    _overwrite_arg(p)


@command("import-libero", "replay a LIBERO HDF5 demo file into this project's layout")(_import_args)
def _import_libero(args: argparse.Namespace) -> dict:
    from annotations.libero_import import import_libero_hdf5

    return import_libero_hdf5(args.file, args.out, suite=args.suite, task=args.task, overwrite=args.overwrite)


def _annotate_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("demos", help="demos HDF5 (from elegant demos or import-libero)")
    p.add_argument("--out", help="annotated HDF5 (default: DEMOS with .annotated.hdf5)")
    p.add_argument("--labels", help="human labels CSV: demo,start_frame,end_frame,criterion,label")
    p.add_argument("--specs", help="directory of per-task YAML spec overrides (<suite>/<task>.yaml)")
    p.add_argument("--gamma", type=float, help="discount of the Monte-Carlo return (default: annotate_file's)")
    p.add_argument("--export-labels", help="also write the final segment labels as CSV here")
    p.add_argument("--resume", action="store_true")
    _overwrite_arg(p)
    _workers_arg(p)


@command("annotate", "label demos with the four ITCs per step and per 25-frame window")(_annotate_args)
def _annotate(args: argparse.Namespace) -> dict:
    from annotations import annotate_file, export_segment_labels

    out = args.out or (args.demos[:-5] if args.demos.endswith(".hdf5") else args.demos) + ".annotated.hdf5"
    summary = annotate_file(
        args.demos,
        out,
        labels_csv=args.labels,
        overrides_dir=args.specs,
        resume=args.resume,
        overwrite=args.overwrite,
        workers=_workers(args),
        **({} if args.gamma is None else {"gamma": args.gamma}),
    )
    if args.export_labels:
        export_segment_labels(out, args.export_labels)
    return summary


def _itc_spec_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("suite")
    p.add_argument("task")
    p.add_argument("--specs", help="directory of per-task YAML spec overrides")


@command("itc-spec", "print the ITC constraint spec derived from a task's BDDL")(_itc_spec_args)
def _itc_spec(args: argparse.Namespace) -> dict:
    from itc import describe_spec

    return describe_spec(args.suite, args.task, overrides_dir=args.specs)


def _train_policy_args(p: argparse.ArgumentParser) -> None:
    from base_suites.runtime.settings import add_settings_arguments
    from elegant.policies.bc_config import BCConfig  # torch-free

    p.add_argument("data", nargs="+", help="demos HDF5 file(s)")
    p.add_argument("--out", required=True)
    add_settings_arguments(p, BCConfig)
    p.add_argument(
        "--successful-only",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="train on the demos whose episode succeeded, as LIBERO's datasets hold (default: on)",
    )
    p.add_argument("--resume", action="store_true")
    _overwrite_arg(p)
    _compute_args(p)


@command("train-policy", "train the BC base policy (GMM head) on demos")(_train_policy_args)
def _train_policy(args: argparse.Namespace) -> dict:
    from base_suites.runtime.settings import config_from_args
    from elegant.policies import train_policy
    from elegant.policies.bc_config import BCConfig

    summary = train_policy(
        args.data,
        args.out,
        config_from_args(args, BCConfig, "train_policy"),
        successful_only=args.successful_only,
        resume=args.resume,
        overwrite=args.overwrite,
        compute=_compute(args),
    )
    summary.pop("loss_history", None)
    return summary


def _train_critic_args(p: argparse.ArgumentParser) -> None:
    from base_suites.runtime.settings import add_settings_arguments
    from critics.config import TrainConfig  # torch-free

    p.add_argument("data", nargs="+", help="annotated HDF5 file(s) (from elegant annotate)")
    p.add_argument("--out", required=True)
    add_settings_arguments(p, TrainConfig, exclude=("paths",))
    p.add_argument("--resume", action="store_true")
    _overwrite_arg(p)
    _compute_args(p)


@command("train-critic", "train the Cal-QL elegance critic offline on annotated demos")(_train_critic_args)
def _train_critic(args: argparse.Namespace) -> dict:
    from base_suites.runtime.settings import config_from_args
    from critics import TrainConfig, train_critic

    config = config_from_args(args, TrainConfig, "train-critic", exclude=("paths",))
    return train_critic(
        args.data, args.out, config, resume=args.resume, overwrite=args.overwrite, compute=_compute(args)
    )


def _rank_check_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "rollouts",
        help="annotated branch rollouts (elegant rollouts --explore-at, then elegant annotate), "
        "best from starts the critic did not train on",
    )
    p.add_argument("--policy", required=True, help="the policy directory that recorded the rollouts")
    p.add_argument(
        "--critic",
        required=True,
        help="critic directory (from train-critic), or comma-separated ones scored as an ensemble",
    )
    p.add_argument("--out", help="also write the result here as JSON")


@command(
    "rank-check",
    "how well a critic ranks a policy's explored alternatives against its own plan, by their annotated outcome",
)(_rank_check_args)
def _rank_check(args: argparse.Namespace) -> dict:
    from base_suites.runtime.io import atomic_write_json
    from elegant.diagnostics.branch_ranking import branch_ranking
    from elegant.evaluation.runner import open_critic, open_policy
    from elegant.policies import as_policy

    result = branch_ranking(
        args.rollouts, as_policy(open_policy(args.policy), seed=0), open_critic(args.critic), progress=True
    )
    if args.out:
        atomic_write_json(args.out, result)
    return result


def _eval_args(p: argparse.ArgumentParser) -> None:
    from base_suites.runtime.settings import add_settings_arguments
    from elegant.evaluation.config import EvalConfig
    from elegant.intervention.config import JITIConfig  # light: no torch

    p.add_argument("--suite", required=True)
    _tasks_arg(p)
    p.add_argument("--policy", required=True, help=POLICY_HELP)
    p.add_argument(
        "--critic",
        help="critic directory (from train-critic), or comma-separated ones: an ensemble whose members "
        "must all prefer an override; required for jiti and always",
    )
    p.add_argument("--out", required=True, help="run directory")
    p.add_argument("--resume", action="store_true", help="skip episodes already in RUN/episodes.jsonl")
    add_settings_arguments(p, EvalConfig, exclude=("jiti",))
    add_settings_arguments(p, JITIConfig)
    _workers_arg(p)
    _compute_args(p)


@command("eval", "evaluate a policy (base, always or JITI) with success, ESR and ITC violations")(_eval_args)
def _eval(args: argparse.Namespace) -> dict:
    from base_suites.runtime.settings import settings_from_args
    from elegant.evaluation.config import EvalConfig
    from elegant.evaluation.runner import evaluate
    from elegant.intervention.config import JITIConfig

    settings = {**settings_from_args(args, EvalConfig, exclude=("jiti",)), **settings_from_args(args, JITIConfig)}
    summary = evaluate(
        args.suite,
        _listed(args.tasks),
        args.policy,
        args.critic,
        EvalConfig().with_settings(**settings),
        out=args.out,
        resume=args.resume,
        workers=_workers(args),
        compute=_compute(args),
    )
    return {k: v for k, v in summary.items() if k != "per_task"}


def _robustness_args(p: argparse.ArgumentParser) -> None:
    from base_suites.runtime.settings import add_settings_arguments
    from elegant.evaluation.config import EvalConfig, RobustnessConfig
    from elegant.intervention.config import JITIConfig

    p.add_argument("--suite", required=True, help="comma-separated suites, e.g. libero_object,libero_goal")
    _tasks_arg(p, "task indices within every suite, e.g. 0-4 or 0,3 (default: all)")
    p.add_argument("--policy", required=True, help=POLICY_HELP)
    p.add_argument("--critic", help="critic directory (or comma-separated ones); required for jiti and always")
    p.add_argument("--out", required=True, help="directory for the runs, robustness.json, report.md and the plot")
    p.add_argument("--resume", action="store_true", help="skip finished runs and episodes in OUT")
    add_settings_arguments(p, RobustnessConfig)
    add_settings_arguments(p, EvalConfig, exclude=("jiti", "perturbation"))
    add_settings_arguments(p, JITIConfig)
    _workers_arg(p)
    _compute_args(p)


@command(
    "robustness",
    "LIBERO-PRO's robustness table (five axes and the language probe) from success and from ESR, in one command",
)(_robustness_args)
def _robustness(args: argparse.Namespace) -> dict:
    from base_suites.runtime.settings import settings_from_args
    from elegant.evaluation.config import EvalConfig, RobustnessConfig
    from elegant.evaluation.robustness import run_robustness
    from elegant.intervention.config import JITIConfig

    config = RobustnessConfig(**settings_from_args(args, RobustnessConfig))
    settings = {
        **settings_from_args(args, EvalConfig, exclude=("jiti", "perturbation")),
        **settings_from_args(args, JITIConfig),
    }
    result = run_robustness(
        [s.strip() for s in args.suite.split(",")],
        args.policy,
        args.critic,
        args.out,
        config,
        EvalConfig().with_settings(**settings),
        tasks=_listed(args.tasks),
        resume=args.resume,
        workers=_workers(args),
        compute=_compute(args),
    )
    return {"out": args.out, "total": {name: result[name]["total"] for name in ("success", "elegant")}}


def _serve_policy_args(p: argparse.ArgumentParser) -> None:
    from elegant.policies.protocol import add_policy_act_argument

    p.add_argument("policy", help="policy directory (from train-policy)")
    p.add_argument("--port", type=int, default=8000, help="port to listen on (0: any free one; default: 8000)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default: 127.0.0.1, this machine only)")
    p.add_argument("--api-key-file", help="require the key in this file (openpi-client's Api-Key header)")
    add_policy_act_argument(p)


@command("serve-policy", "serve a train-policy policy over openpi's websocket protocol (stop with Ctrl-C)")(
    _serve_policy_args
)
def _serve_policy(args: argparse.Namespace) -> None:
    from base_suites.runtime.errors import UserInputError
    from elegant.policies.server import serve_policy

    if not 0 <= args.port <= 65535:
        raise UserInputError(f"--port {args.port}: expected 0..65535")
    api_key = None
    if args.api_key_file is not None:
        try:
            with open(args.api_key_file, encoding="utf-8") as f:
                api_key = f.read().strip()
        except (OSError, UnicodeDecodeError) as exc:
            raise UserInputError(f"{args.api_key_file}: cannot read the API key ({exc.__class__.__name__})") from None
        if not api_key:
            raise UserInputError(f"{args.api_key_file}: the API key file is empty")

    def ready(address: str) -> None:
        print(f"serving {args.policy} at {address} (Ctrl-C stops)", file=sys.stderr, flush=True)

    serve_policy(args.policy, host=args.host, port=args.port, act=args.policy_act, api_key=api_key, ready=ready)


def _gate_args(p: argparse.ArgumentParser) -> None:
    from base_suites.runtime.settings import add_settings_arguments
    from elegant.intervention.gate import GateConfig

    p.add_argument("base_run", help="a base-mode run on validation starts (e.g. --init-states 0-24)")
    p.add_argument("jiti_run", help="the JITI run to judge, on the same starts")
    p.add_argument(
        "--always",
        help="an `always` run on the same starts: a task may then re-rank every decision where that did best",
    )
    add_settings_arguments(p, GateConfig)
    p.add_argument("--out", required=True, help="gate file (JSON) for elegant eval --gate")
    _overwrite_arg(p)


@command(
    "gate",
    "choose per task base, JITI (or always) by what, on validation starts, made more episodes elegant than it spoiled",
)(_gate_args)
def _gate(args: argparse.Namespace) -> dict:
    from base_suites.runtime.settings import config_from_args
    from elegant.intervention.gate import GateConfig, write_gate

    config = config_from_args(args, GateConfig, "gate")
    return write_gate(
        args.base_run, args.jiti_run, args.out, always_run=args.always, budget=config.budget, overwrite=args.overwrite
    )


def _lifelong_args(p: argparse.ArgumentParser) -> None:
    from base_suites.runtime.settings import add_settings_arguments, index_list
    from elegant.evaluation.config import LifelongConfig

    p.add_argument("data", nargs="+", help="demos HDF5 file(s) holding the demos of every task (from elegant demos)")
    p.add_argument("--suite", required=True)
    order = p.add_mutually_exclusive_group(required=True)
    _tasks_arg(order, "task indices in learning order, e.g. 0-2 or 2,0,1")
    order.add_argument(
        "--task-order", type=int, metavar="K", help="all ten tasks in LIBERO's task order K (0: the suite's own order)"
    )
    p.add_argument("--out", required=True, help="run directory")
    add_settings_arguments(p, LifelongConfig)
    p.add_argument(
        "--seeds",
        type=index_list,
        help="one run per seed (OUT/seed_<s>/), reported as mean and standard deviation, e.g. 0,1,2 (not with --seed)",
    )
    p.add_argument(
        "--pretrained",
        metavar="POLICY_DIR",
        help="start the first task from this policy, e.g. one trained on libero_90 (LIBERO-100's protocol): its "
        "hidden layers and head, or all of it with --encoding goal-relative",
    )
    p.add_argument("--resume", action="store_true", help="skip finished stages and evaluations in OUT")
    _workers_arg(p)
    _compute_args(p)


@command(
    "lifelong",
    "LIBERO's lifelong protocol (SeqL, ER, EWC, PackNet, multitask): FWT, NBT, AUC from success and from ESR",
)(_lifelong_args)
def _lifelong(args: argparse.Namespace) -> dict:
    from base_suites import task_order
    from base_suites.runtime.errors import UserInputError
    from base_suites.runtime.settings import settings_from_args, with_overrides
    from elegant.evaluation.config import LifelongConfig
    from elegant.evaluation.lifelong import run_lifelong
    from elegant.evaluation.lifelong_table import run_lifelong_seeds

    settings = settings_from_args(args, LifelongConfig)
    config = with_overrides(LifelongConfig(), settings, "lifelong")
    tasks = _listed(args.tasks) if args.tasks is not None else task_order(args.suite, args.task_order)
    common = {
        "resume": args.resume,
        "workers": _workers(args),
        "compute": _compute(args),
        "pretrained": args.pretrained,
    }
    if args.seeds is None:
        result = run_lifelong(args.suite, tasks, args.data, args.out, config, **common)
        return {"out": args.out, "metrics": result["metrics"], "metrics_elegant": result["metrics_elegant"]}
    if "seed" in settings:
        raise UserInputError("lifelong: give --seed for one run or --seeds for several, not both")
    summary = run_lifelong_seeds(args.suite, tasks, args.data, args.out, args.seeds, config, **common)
    means = {source: {k: v["mean"] for k, v in summary[source].items()} for source in ("metrics", "metrics_elegant")}
    return {"out": args.out, "seeds": summary["seeds"], **means}


def _lifelong_table_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "runs", nargs="+", help="finished elegant lifelong outputs, one per algorithm (with or without --seeds)"
    )
    p.add_argument("--out", required=True, help="directory for table.md, table.json and the plots")
    _overwrite_arg(p)


@command("lifelong-table", "LIBERO's table of lifelong algorithms side by side, from success and from ESR")(
    _lifelong_table_args
)
def _lifelong_table(args: argparse.Namespace) -> None:
    from elegant.evaluation.lifelong_table import lifelong_table

    print(lifelong_table(args.runs, args.out, overwrite=args.overwrite)["markdown"])


def _report_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("runs", nargs="+", help="run directories from elegant eval")
    p.add_argument("--out", help="directory for the comparison (markdown + PNG)")
    p.add_argument(
        "--videos",
        type=int,
        default=0,
        metavar="K",
        help="replay up to K episodes per group and run (made elegant, spoiled, inelegant successes) as MP4s "
        "under OUT/videos/ (default: 0, none)",
    )


@command("report", "compare evaluation runs side by side")(_report_args)
def _report(args: argparse.Namespace) -> None:
    from elegant.reporting.report import compare_runs

    result = compare_runs(args.runs, args.out, videos=args.videos)
    print(result["markdown"])


def _quickstart_args(p: argparse.ArgumentParser) -> None:
    from base_suites.runtime.jobs import available_cores

    p.add_argument("--out", default="runs/quickstart")
    p.add_argument(
        "--recipe",
        default="quickstart",
        help="a chain recipe: a name under configs/ or a YAML file (default: quickstart)",
    )
    p.add_argument("--suite", help="run the recipe on this suite instead")
    p.add_argument("--task", type=int, help="run the recipe on this task index instead")
    p.add_argument("--seed", type=int, help="every stage's seed (default: the recipe's)")
    p.add_argument("--json", action="store_true", help="print the result as JSON instead of a summary")
    _workers_arg(p, default=available_cores())
    _compute_args(p)


@command(
    "quickstart",
    "JITI's recipe on one task at small sizes: demos -> annotate -> policy -> branch rollouts -> critic -> "
    "eval base and JITI -> report",
)(_quickstart_args)
def _quickstart(args: argparse.Namespace) -> dict | None:
    from base_suites.runtime.settings import with_overrides
    from elegant.chain_config import load_recipe
    from elegant.pipeline import effects_text, quickstart

    changes = {
        "suites": args.suite and (args.suite,),
        "tasks": None if args.task is None else (args.task,),
        "seed": args.seed,
    }
    recipe = with_overrides(load_recipe(args.recipe), {k: v for k, v in changes.items() if v is not None})
    result = quickstart(args.out, recipe, workers=_workers(args), compute=_compute(args))
    if not args.json:
        print(effects_text(result))
        return None
    # one suite and one task: the per-suite and per-task rows repeat the pooled numbers
    return {k: v for k, v in result.items() if k not in ("per_suite", "per_task")}


class _OneLineParser(argparse.ArgumentParser):
    """argparse with a mistake reported in one line (argparse's default prints the whole usage first)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(
        prog="elegant", description="Measure and improve how elegantly policies execute LIBERO tasks."
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_OneLineParser)
    for name, (help_text, add_arguments, run) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text, allow_abbrev=False)
        add_arguments(p)
        p.set_defaults(run=run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from base_suites.runtime.errors import UserInputError

    args = build_parser().parse_args(argv)
    warnings.formatwarning = lambda message, *_, **__: f"elegant {args.command}: warning: {message}\n"
    os.environ.setdefault("RL_LOGGING_LEVEL", "WARNING")  # torchrl's info lines would break the progress bars
    try:
        result = args.run(args)
    except UserInputError as exc:
        print(f"elegant {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"elegant {args.command}: interrupted; rerun with --resume where supported", file=sys.stderr)
        return 130
    except OSError as exc:  # a full disk, a lost mount, a permission changed mid-run: finished work stays
        where = f"{exc.filename}: " if exc.filename else ""
        cause = " ".join(str(exc.strerror or exc).split())  # HDF5's messages span lines
        print(
            f"elegant {args.command}: error: {where}{cause}; "
            "what finished is kept, rerun with --resume where supported",
            file=sys.stderr,
        )
        return 1
    if isinstance(result, dict):
        _print_json(result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
