"""How each task runs under JITI (base, JITI or `always`), decided on validation starts, never on the evaluation's.

Whether a critic's choices help a task is an empirical question per task (no per-state Q threshold tells
the tasks JITI helps from those it spoils), so it is answered the way a researcher would: run the base
policy and JITI on validation starts (the init states the critic's rollouts came from, e.g.
`--init-states 0-24`), pair their episodes (same task, same episode index, hence the same start), and
enable JITI on a task only if it made more episodes elegant than it spoiled there. `elegant eval
--gate gate.json` then runs the other tasks as the base policy, and refuses a gate validated on any of
the evaluation's own starts. A gate's choices are evidence about one policy, critic and set of JITI
settings, so the gate records them and refuses an evaluation, or an `always` run, with any other.

Some tasks need more than JITI's rare interventions (a base policy that fails half its episodes there):
given an `always` run on the same validation starts, the gate may choose `always` for such a task, within
a budget on the suite's interventions (by default 40% of `always`'s on every task), so the suite stays a
sparse intervener while the tasks that need constant steering get it. How well validation predicts the
held-out effect is measured in benchmarks/RESULTS.md (the JITI recipe).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from base_suites import UserInputError, check_same_stack
from base_suites.runtime.io import atomic_write, read_json_file
from base_suites.runtime.outputs import check_output
from base_suites.runtime.records import RecordFormat, fill_missing
from base_suites.runtime.settings import setting
from elegant.evaluation.episode_log import EpisodeLog
from elegant.evaluation.run_record import read_run_config
from elegant.intervention.config import mode_record


def _gate_from_v3(record: dict[str, Any]) -> dict[str, Any]:
    """A version-3 gate as version 4: gates validated before the policy act was a setting ran its default."""
    if isinstance(record.get("agent"), dict):
        record["agent"] = fill_missing(record["agent"], {"policy_act": "mode"})
    return record


GATE_RECORD = RecordFormat("libero-elegant-gate", 4, {3: _gate_from_v3})
GATED_MODES = ("jiti", "always")
# the fields of a run's config.json that decide what a gated task's JITI or `always` does: a gate's
# choices hold only for the policy, critic and JITI settings its validation runs used
AGENT_FIELDS = ("policy", "policy_act", "critic", "jiti")


@dataclass(frozen=True)
class GateConfig:
    """How a gate chooses (each field is also an option of `elegant gate`)."""

    budget: float = setting(
        0.4,
        "with --always: the suite's interventions per episode at most this share of always's (JITI's promise "
        "is to intervene rarely)",
    )


INTERVENTION_BUDGET: float = GateConfig.budget


def _run(path: str | os.PathLike, mode: str) -> tuple[dict[str, Any], dict[tuple[str, int], dict[str, Any]]]:
    """A finished run's config and its episodes by (task, episode), refused unless it ran `mode`."""
    run = Path(path)
    config = read_run_config(read_json_file(run / "config.json", "run config"), str(run / "config.json"))
    if config.get("mode") != mode:
        raise UserInputError(
            f"{run / 'config.json'}: field 'mode' is {config.get('mode')!r}; the gate needs a {mode!r} run here"
        )
    records = EpisodeLog(run / "episodes.jsonl").records
    return config, {(r["task"], int(r["episode"])): r for r in records}


def _paired_effects(
    base: dict[tuple[str, int], dict[str, Any]], runs: dict[str, dict[tuple[str, int], dict[str, Any]]]
) -> dict[str, dict[str, Any]]:
    """Per task, each mode's episodes made elegant and spoiled against base and its interventions per
    episode, over the episodes every run finished."""
    keys = set(base).intersection(*runs.values())
    tasks: dict[str, dict[str, Any]] = {}
    for key in sorted(keys):
        row = tasks.setdefault(
            key[0], {"episodes": 0, **{m: {"gained": 0, "lost": 0, "interventions": 0.0} for m in runs}}
        )
        row["episodes"] += 1
        for mode, episodes in runs.items():
            effect, b, r = row[mode], base[key], episodes[key]
            effect["gained"] += bool(r["elegant"]) and not b["elegant"]
            effect["lost"] += bool(b["elegant"]) and not r["elegant"]
            effect["interventions"] += float(r["interventions"])
    for row in tasks.values():
        for mode in runs:
            row[mode]["interventions"] /= row["episodes"]
    return tasks


def _agent(config: dict[str, Any], mode: str = "jiti") -> dict[str, Any]:
    """The AGENT_FIELDS of a run's config (or a gate's "agent"), its JITI settings cut to those `mode`
    uses (`mode_record`): what a gate records as the JITI it validated."""
    agent = {field: config.get(field) for field in AGENT_FIELDS}
    if isinstance(agent["jiti"], dict):
        agent["jiti"] = mode_record(agent["jiti"], mode)
    return agent


def _flat(agent: dict[str, Any], mode: str) -> dict[str, Any]:
    """The AGENT_FIELDS of `agent` (read as `_agent` does) with the JITI settings spelled out as
    "jiti.<setting>", so a mismatch names the setting."""
    flat = _agent(agent, mode)
    jiti = flat.pop("jiti")
    return {**flat, **({f"jiti.{k}": v for k, v in sorted(jiti.items())} if isinstance(jiti, dict) else {"jiti": jiti})}


def _refuse_other_agent(
    path: str | os.PathLike,
    expected: dict[str, Any],
    got: dict[str, Any],
    whose: str,
    prefix: str = "",
    mode: str = "jiti",
) -> None:
    """Refuse `got`'s policy, critic and JITI settings (read as `_flat` does, those of `mode`; at `prefix`
    in the file at `path`) unless they equal `expected`'s, naming the first field that differs."""
    want, have = _flat(expected, mode), _flat(got, mode)
    for field in dict.fromkeys([*want, *have]):
        if want.get(field) != have.get(field):
            raise UserInputError(
                f"{path}: field '{prefix}{field}' is {have.get(field)!r} but {whose} is {want.get(field)!r}; "
                "a gate holds only for the policy, critic and JITI settings it validated"
            )


def _net(row: dict[str, Any], mode: str) -> int:
    return 0 if mode == "base" else row[mode]["gained"] - row[mode]["lost"]


def _rate(row: dict[str, Any], mode: str) -> float:
    return 0.0 if mode == "base" else row[mode]["interventions"]


def _choose_modes(tasks: dict[str, dict[str, Any]], modes: tuple[str, ...], budget: float) -> float | None:
    """Set each task's "mode": the one that made the most more episodes elegant than it spoiled, base
    unless one made more elegant than it spoiled (ties go to the fewer interventions). With `always`
    among the modes, tasks are moved back from `always` to their next best mode, cheapest loss per
    saved intervention first, until the suite's interventions per episode are at most `budget` times
    `always`'s on every task; returns that limit (None without `always`)."""
    order = ("base", *modes)  # fewest interventions first, so a tie keeps the sparser mode

    def best(row: dict[str, Any], among: tuple[str, ...]) -> str:
        return max(among, key=lambda m: (_net(row, m), -among.index(m)))

    for row in tasks.values():
        row["mode"] = best(row, order)
    if "always" not in modes:
        return None
    sparser = tuple(m for m in order if m != "always")
    fallback = {task: best(row, sparser) for task, row in tasks.items()}

    def cost_of_moving_back(task: str) -> tuple[float, str]:
        row, back = tasks[task], fallback[task]
        saved = _rate(row, "always") - _rate(row, back)
        return (_net(row, "always") - _net(row, back)) / max(saved, 1e-9), task

    limit = budget * sum(_rate(row, "always") for row in tasks.values()) / len(tasks)
    while sum(_rate(row, row["mode"]) for row in tasks.values()) / len(tasks) > limit:
        steered = [task for task, row in tasks.items() if row["mode"] == "always"]
        if not steered:
            break  # JITI alone is over the budget: nothing left to move back
        task = min(steered, key=cost_of_moving_back)
        tasks[task]["mode"] = fallback[task]
    return limit


def task_gate(
    base_run: str | os.PathLike,
    jiti_run: str | os.PathLike,
    always_run: str | os.PathLike | None = None,
    budget: float = INTERVENTION_BUDGET,
) -> dict[str, Any]:
    """Per task, JITI's (and `always`'s) paired effect on ESR in validation runs, and the mode to run it in.

    The runs must share suite, seed, init states and episode settings (so episode i of a task starts
    alike in all) and the policy; the JITI and `always` runs also the critic and JITI settings, which the
    gate records under "agent". A task runs JITI where JITI made more episodes elegant than it spoiled, and with
    `always_run` it may instead re-rank every decision where `always` did better still, as long as the
    suite's interventions stay within `budget` times `always`'s (JITI's promise is to intervene rarely:
    the recipe holds it to 40%).
    """
    base_config, base = _run(base_run, "base")
    paths = {"jiti": jiti_run, **({} if always_run is None else {"always": always_run})}
    runs, configs = {}, {}
    for mode, path in paths.items():
        configs[mode], runs[mode] = _run(path, mode)
        for field in ("suite", "seed", "init_states", "perturbation", "max_steps", "policy"):
            if base_config.get(field) != configs[mode].get(field):
                raise UserInputError(
                    f"{path}: field {field!r} is {configs[mode].get(field)!r} but the base run {base_run} has "
                    f"{base_config.get(field)!r}; validate every run on the same starts with the same policy"
                )
    check_same_stack(
        [(str(base_run), base_config.get("stack"))] + [(str(paths[m]), configs[m].get("stack")) for m in paths],
        "a gate",
    )
    agent = _agent(configs["jiti"])
    if always_run is not None:
        _refuse_other_agent(always_run, agent, configs["always"], f"the JITI run {jiti_run}'s", mode="always")
    if not 0 < budget <= 1:
        raise UserInputError(f"gate budget must be in (0, 1] (a share of always's interventions), got {budget}")
    tasks = _paired_effects(base, runs)
    if not tasks:
        raise UserInputError(
            f"{base_run} and {', '.join(map(str, paths.values()))} share no finished episode of any task"
        )
    limit = _choose_modes(tasks, tuple(runs), budget)
    return {
        "format": GATE_RECORD.tag,
        "suite": base_config["suite"],
        "init_states": base_config.get("init_states"),
        "base_run": os.path.abspath(base_run),
        **{f"{m}_run": os.path.abspath(p) for m, p in paths.items()},
        "agent": agent,
        **({} if limit is None else {"budget": budget, "interventions_limit": limit}),
        "tasks": tasks,
    }


def write_gate(
    base_run: str | os.PathLike,
    jiti_run: str | os.PathLike,
    out: str | os.PathLike,
    always_run: str | os.PathLike | None = None,
    budget: float = INTERVENTION_BUDGET,
    overwrite: bool = False,
) -> dict[str, Any]:
    """`task_gate` written atomically to `out` (JSON); returns it. An existing gate file is replaced only
    with `overwrite` (runs that used it would otherwise no longer match it)."""
    check_output(out, "file", overwrite=overwrite, resumable=False)
    gate = task_gate(base_run, jiti_run, always_run, budget)
    atomic_write(out, json.dumps(gate, indent=2))
    return gate


def read_gate(
    path: str | os.PathLike, suite: str, tasks: list[str], init_states: list[int] | None, agent: dict[str, Any]
) -> dict[str, str]:
    """{task: the mode it runs in (base, jiti or always)} for an evaluation of `tasks` of `suite` from
    `init_states` (None: all) whose `agent` is {"policy", "critic", "jiti"} as its config.json names them.

    Refuses a gate of another suite, one missing any of the tasks, one validated with another policy,
    critic or JITI setting (its choices say nothing of this one's), and one validated on starts the
    evaluation uses: a gate chosen on the evaluated starts would report its own selection as an effect."""
    gate = GATE_RECORD.upgrade(read_json_file(path, "gate"), str(path))
    if gate.get("suite") != suite:
        raise UserInputError(f"{path}: field 'suite' is {gate.get('suite')!r} but the evaluation is on {suite!r}")
    _refuse_other_agent(path, agent, gate.get("agent") or {}, "this evaluation's", prefix="agent.")
    missing = [t for t in tasks if t not in gate.get("tasks", {})]
    if missing:
        raise UserInputError(f"{path}: field 'tasks' lacks {', '.join(missing)}; validate those tasks too")
    validated = gate.get("init_states")
    if validated is None or init_states is None or set(validated) & set(init_states):
        shared = (
            "all init states" if validated is None or init_states is None else sorted(set(validated) & set(init_states))
        )
        raise UserInputError(
            f"{path}: field 'init_states' overlaps the evaluation's starts ({shared}); validate on other starts, "
            "e.g. --init-states 0-24 for the gate and 25-49 for the evaluation"
        )
    modes = {t: gate["tasks"][t].get("mode") for t in tasks}
    wrong = [t for t, m in modes.items() if m not in ("base", *GATED_MODES)]
    if wrong:
        raise UserInputError(
            f"{path}: field 'tasks.{wrong[0]}.mode' is {modes[wrong[0]]!r}; expected one of base, "
            f"{', '.join(GATED_MODES)}"
        )
    return modes
