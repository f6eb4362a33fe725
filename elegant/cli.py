"""The `elegant` command line: each subcommand parses its arguments and calls one library function.

Heavy imports (robosuite, LIBERO, torch) happen inside the command functions, so `elegant --help` is
instant. A user mistake (`UserInputError`) becomes one line on stderr and exit status 2.
"""
from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence

COMMANDS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None], Callable[[argparse.Namespace], object]]] = {}


def command(name: str, help_text: str):
    """Register a subcommand: the decorated function adds its arguments, `run` does the work."""

    def register(add_arguments):
        def bind(run):
            COMMANDS[name] = (help_text, add_arguments, run)
            return run

        return bind

    return register


def _print_json(result: object) -> None:
    print(json.dumps(result, indent=2, default=str))


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


def _task_list(text: str | None) -> list[int] | None:
    from base_suites.errors import UserInputError

    if text is None:
        return None
    try:
        return [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise UserInputError(f"--tasks {text!r}: expected comma-separated task indices, e.g. 0,3") from None


def _demos_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--suite", required=True)
    p.add_argument("--tasks", help="comma-separated task indices (default: all 10)")
    p.add_argument("--episodes", type=int, default=50, help="episodes per task")
    p.add_argument("--quality", default="clean", help="clean, mixed, or knob=prob,... (knobs: collide, drop, misplace, tilt, wrong_order, jerky, regrasp)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True)
    p.add_argument("--resume", action="store_true", help="continue an interrupted file")


@command("demos", "roll out scripted experts and write a LIBERO-layout HDF5 demos file")(_demos_args)
def _demos(args: argparse.Namespace) -> dict:
    from annotations.collect import collect_demos
    from base_suites.experts import parse_quality

    return collect_demos(args.suite, _task_list(args.tasks), args.episodes, args.out, quality=parse_quality(args.quality),
                         seed=args.seed, resume=args.resume)


def _import_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help="a LIBERO HDF5 demonstration file")
    p.add_argument("--out", required=True)
    p.add_argument("--suite", help="suite of the task (default: found from the file's bddl_file_name)")
    p.add_argument("--task", type=int, help="task index (with --suite)")


@command("import-libero", "replay a LIBERO HDF5 demo file into this project's layout")(_import_args)
def _import_libero(args: argparse.Namespace) -> dict:
    from annotations.libero_import import import_libero_hdf5

    return import_libero_hdf5(args.file, args.out, suite=args.suite, task=args.task)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="elegant", description="Measure and improve how elegantly policies execute LIBERO tasks.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (help_text, add_arguments, run) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        add_arguments(p)
        p.set_defaults(run=run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from base_suites.errors import UserInputError

    args = build_parser().parse_args(argv)
    try:
        result = args.run(args)
    except UserInputError as exc:
        print(f"elegant {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"elegant {args.command}: interrupted; rerun with --resume where supported", file=sys.stderr)
        return 130
    if isinstance(result, dict):
        _print_json(result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
