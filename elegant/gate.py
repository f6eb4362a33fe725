"""Which tasks JITI should run on, decided on validation starts, never on the evaluation's.

JITI with one critic helps some tasks and spoils others: on libero_goal/4 it made 14 more episodes
elegant and spoiled none, on libero_goal/0 it spoiled 7 and rescued none, and no per-state Q threshold
tells the two apart (the Q bands at the interventions overlap). Whether the critic's choices help a
task is an empirical question per task, so it is answered the way a researcher would: run the base
policy and JITI on validation starts (the init states the critic's rollouts came from, e.g.
`--init-states 0-24`), pair their episodes (same task, same episode index, hence the same start), and
enable JITI on a task only if it made more episodes elegant than it spoiled there. `elegant eval
--gate gate.json` then runs the other tasks as the base policy, and refuses a gate validated on any of
the evaluation's own starts.

Measured (benchmarks/RESULTS.md, sessions 25 and 28): with the drop trigger alone, 50 validation
episodes per task from the critic's rollout starts did not predict the held-out effect on libero_goal
or libero_object (they would have switched JITI off on libero_goal/4, +14 ESR held out). With the
steered warm-up the per-task effects are larger: on libero_object 25 validation episodes per task
switched off the tasks the base policy already does perfectly, and the held-out ESR gain rose from
+8.8 to +11.6 (spoiled episodes 27 -> 10); on libero_goal it fell from +4.8 to +3.8.
Validating instead on nudged starts (`--perturbation init@nudge`: starts 0-24 with the task objects
moved up to 2 cm, which no critic saw; session 30) gave gates no better: +11.0 on libero_object, +3.4
on libero_goal.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from base_suites import UserInputError
from base_suites.atomic import atomic_write, read_json_file
from elegant.episode_log import EpisodeLog

GATE_FORMAT = "libero-elegant-gate/1"


def _run(path: str | os.PathLike, mode: str) -> tuple[dict[str, Any], dict[tuple[str, int], dict[str, Any]]]:
    """A finished run's config and its episodes by (task, episode), refused unless it ran `mode`."""
    run = Path(path)
    config = read_json_file(run / "config.json", "run config")
    if config.get("mode") != mode:
        raise UserInputError(f"{run / 'config.json'}: field 'mode' is {config.get('mode')!r}; the gate needs a {mode!r} run here")
    records = EpisodeLog(run / "episodes.jsonl").records
    return config, {(r["task"], int(r["episode"])): r for r in records}


def task_gate(base_run: str | os.PathLike, jiti_run: str | os.PathLike) -> dict[str, Any]:
    """Per task, JITI's paired effect on ESR in a validation pair of runs and whether to enable it.

    The runs must share suite, seed, init states and episode settings (so episode i of a task starts
    alike in both). A task is enabled when JITI's episodes turned elegant outnumber those it spoiled.
    """
    base_config, base = _run(base_run, "base")
    jiti_config, jiti = _run(jiti_run, "jiti")
    for field in ("suite", "seed", "init_states", "perturbation", "max_steps"):
        if base_config.get(field) != jiti_config.get(field):
            raise UserInputError(f"{jiti_run}: field {field!r} is {jiti_config.get(field)!r} but the base run {base_run} has "
                                 f"{base_config.get(field)!r}; validate both on the same starts")
    tasks: dict[str, dict[str, Any]] = {}
    for key in sorted(set(base) & set(jiti)):
        row = tasks.setdefault(key[0], {"episodes": 0, "gained": 0, "lost": 0})
        row["episodes"] += 1
        row["gained"] += bool(jiti[key]["elegant"]) and not base[key]["elegant"]
        row["lost"] += bool(base[key]["elegant"]) and not jiti[key]["elegant"]
    if not tasks:
        raise UserInputError(f"{base_run} and {jiti_run} share no finished episode of any task")
    for row in tasks.values():
        row["enabled"] = row["gained"] > row["lost"]
    return {"format": GATE_FORMAT, "suite": base_config["suite"], "init_states": base_config.get("init_states"),
            "base_run": os.path.abspath(base_run), "jiti_run": os.path.abspath(jiti_run), "tasks": tasks}


def write_gate(base_run: str | os.PathLike, jiti_run: str | os.PathLike, out: str | os.PathLike) -> dict[str, Any]:
    """`task_gate` written atomically to `out` (JSON); returns it."""
    gate = task_gate(base_run, jiti_run)
    atomic_write(out, json.dumps(gate, indent=2))
    return gate


def read_gate(path: str | os.PathLike, suite: str, tasks: list[str], init_states: list[int] | None) -> dict[str, bool]:
    """{task: JITI enabled} for an evaluation of `tasks` of `suite` from `init_states` (None: all).

    Refuses a gate of another suite, one missing any of the tasks, and one validated on starts the
    evaluation uses: a gate chosen on the evaluated starts would report its own selection as an effect."""
    gate = read_json_file(path, "gate")
    if not isinstance(gate, dict) or gate.get("format") != GATE_FORMAT:
        raise UserInputError(f"{path}: field 'format' is not {GATE_FORMAT!r}; write the gate with `elegant gate`")
    if gate.get("suite") != suite:
        raise UserInputError(f"{path}: field 'suite' is {gate.get('suite')!r} but the evaluation is on {suite!r}")
    missing = [t for t in tasks if t not in gate.get("tasks", {})]
    if missing:
        raise UserInputError(f"{path}: field 'tasks' lacks {', '.join(missing)}; validate those tasks too")
    validated = gate.get("init_states")
    if validated is None or init_states is None or set(validated) & set(init_states):
        shared = "all init states" if validated is None or init_states is None else sorted(set(validated) & set(init_states))
        raise UserInputError(f"{path}: field 'init_states' overlaps the evaluation's starts ({shared}); validate on other starts, "
                             "e.g. --init-states 0-24 for the gate and 25-49 for the evaluation")
    return {t: bool(gate["tasks"][t]["enabled"]) for t in tasks}
