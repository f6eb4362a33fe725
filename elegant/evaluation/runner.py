"""The evaluation runner: roll a (JITI-wrapped) policy out on LIBERO tasks and record how elegantly it works.

A run directory holds::

    config.json      what the run is (suite, tasks, policy, critic, mode, seed, JITI settings, ...)
    episodes.jsonl   one JSON line per finished episode, appended and flushed as it finishes (with several
                     workers, in the order they finish)
    episodes_sorted.jsonl  the same lines by task and episode index (written at the end): line i of two
                     runs with the same seed and episodes then starts alike
    traces/          <suite>_<task>_<episode>.json: JITI's decision log of each episode (for plots) and what
                     replays it (the executed actions and a digest of the final simulator state)
    summary.json     metrics overall and per task (written atomically at the end)
    report.md, *.png the human-readable report

Episode i of a task starts from init state `episode_start(seed, suite, task, i)`, a function of the run
seed, the task and i only, never of the mode: runs of the modes base / always / jiti with the same seed
compare on identical starts. Resuming skips the finished episodes and refuses a directory whose
config.json describes a different run (only the number of episodes may grow).
"""

from __future__ import annotations

import json
import os
import shutil
import warnings
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from annotations.format import task_key
from base_suites import UserInputError, check_same_stack, make_env, stack_record, task_specs
from base_suites.rollout import ActionLog, run_episode
from base_suites.runtime.compute import ComputeConfig, device_kind, use_compute
from base_suites.runtime.io import atomic_write, changed_fields, read_json_file
from base_suites.runtime.jobs import Workers, check_picklable, check_workers, run_jobs
from base_suites.runtime.locks import output_lock
from base_suites.runtime.outputs import check_output
from base_suites.runtime.seeds import derive_seed
from elegant.evaluation.config import EvalConfig
from elegant.evaluation.episode_log import EpisodeLog, run_records
from elegant.evaluation.metrics import summarize
from elegant.evaluation.run_record import RUN_RECORD
from elegant.intervention.jiti import JITI
from elegant.policies.specs import describe_policy, open_policy
from elegant.reporting.replay import replay_record
from elegant.reporting.report import write_run_report


def episode_start(
    seed: int, suite: str, task_index: int, episode: int, n_init_states: int, init_states: Sequence[int] | None = None
) -> tuple[int, int]:
    """(init-state index, env reset seed) of episode `episode` of a task.

    The init states (all `n_init_states`, or only `init_states`, e.g. those a critic's rollouts did not
    use) are visited in a seeded permutation per task, so the first n episodes use n distinct starts (as
    LIBERO's 50-episode protocol does); the reset seed drives per-episode randomness such as
    perturbation placements. Neither depends on the mode or on the other episodes.
    """
    pool = check_init_states(init_states, n_init_states)
    task = zlib.crc32(task_key(suite, task_index).encode())
    order = np.random.default_rng([int(seed), task]).permutation(len(pool))
    reset_seed = derive_seed(seed, task, episode)
    return pool[int(order[int(episode) % len(pool)])], reset_seed


def check_init_states(init_states: Sequence[int] | None, n_init_states: int) -> list[int]:
    """The init-state indices to draw starts from (all by default), refusing an empty or out-of-range set."""
    if init_states is None:
        return list(range(int(n_init_states)))
    pool = sorted({int(i) for i in init_states})
    if not pool or pool[0] < 0 or pool[-1] >= n_init_states:
        raise UserInputError(f"init states {list(init_states)}: expected indices in 0..{n_init_states - 1}")
    return pool


def _describe(obj: Any) -> str | None:
    """How config.json names a critic: its directory (comma-separated directories for an ensemble), or the
    qualified name of its type (as `describe_policy` names a policy object)."""
    if obj is None:
        return None
    if isinstance(obj, (str, os.PathLike)):
        return ",".join(os.path.abspath(path) for path in os.fspath(obj).split(","))
    return describe_policy(obj)


def open_critic(critic: Any) -> Any:
    """A critic directory loaded (`critics.load`), comma-separated directories loaded as one ensemble
    (`critics.load_ensemble`), or a critic object (or None) passed through."""
    if isinstance(critic, (str, os.PathLike)):
        import critics

        paths = str(critic).split(",")
        return critics.load(paths[0]) if len(paths) == 1 else critics.load_ensemble(paths)
    return critic


def build_agent(policy: Any, critic: Any, config: EvalConfig, device: str = "cpu") -> JITI:
    """The evaluated agent: `policy` (acting as `config.policy_act` says) and `critic` opened (directories
    or objects) and wrapped in JITI with `config.jiti`, seeded by the run's seed. On another `device` than
    the CPU, a BC policy and the critic score there (`BCPolicy.to`, `Critic.to`); other policies decide
    where they run themselves."""
    from elegant.policies.bc_policy import BCPolicy

    opened, scorer = open_policy(policy, config.policy_act, replan_steps=config.replan_steps), open_critic(critic)
    if device != "cpu":
        if isinstance(opened, BCPolicy):
            opened.to(device)
        if scorer is not None:
            scorer.to(device)
    return JITI(opened, scorer, config.jiti, seed=config.seed)


def _prepare_run_dir(out: Path, config: dict[str, Any]) -> None:
    path = out / "config.json"
    if not path.exists() and (out / "episodes.jsonl").exists():
        raise UserInputError(f"{out} holds episodes.jsonl without config.json; choose another directory")
    if path.exists():
        stored = RUN_RECORD.upgrade(read_json_file(path, "run config"), str(path))
        check_same_stack([(str(path), stored.get("stack")), ("this run", config["stack"])], "a resumed run")
        changed = changed_fields(stored, config, ignore=("episodes", "stack"))
        if changed:  # another mode is named first: it explains the settings that differ with it
            key, before, now = next((c for c in changed if c[0] == "mode"), changed[0])
            raise UserInputError(
                f"{path}: field {key!r} is {before!r} but this run has {now!r}; "
                "resume only with the same settings (only episodes may change)"
            )
    (out / "traces").mkdir(parents=True, exist_ok=True)
    atomic_write(path, json.dumps(config, indent=2))


class RepeatedStartsWarning(UserWarning):
    """An evaluation asks for more episodes per task than it has starts (the summary counts the starts)."""


def _remove_refused_run(out: Path) -> None:
    """Remove what a run refused before any episode finished wrote, so that the corrected command can
    use the same directory."""
    for name in ("config.json", "episodes.jsonl"):
        (out / name).unlink(missing_ok=True)
    shutil.rmtree(out / "traces", ignore_errors=True)
    if not any(out.iterdir()):
        out.rmdir()


def _run_episode(
    env, agent: JITI, monitor, init_index: int, reset_seed: int
) -> tuple[dict[str, Any], Any, dict[str, Any]]:
    """One rollout (`base_suites.rollout.run_episode`, judged by the ITC monitor); returns the episode's
    numbers, the ITC verdict and what replays it (`elegant.reporting.replay`)."""
    obs, _ = env.reset(seed=reset_seed, options={"init_state": init_index})
    monitor.reset()
    agent.reset(env.metadata, seed=reset_seed)
    actions = ActionLog()
    run = run_episode(env, agent, obs, [monitor, actions])
    verdict = monitor.verdict(bool(run.info["success"]))
    numbers = {
        "success": bool(verdict.success),
        "elegant": bool(verdict.elegant),
        "violated": sorted(verdict.violated),
        "interventions": agent.interventions,
        "overrides": agent.overrides,
        "steps": run.steps,
        # per step: a chunked policy decides every few steps
        "decision_time": float(sum(d.time for d in agent.log) / run.steps),
        "env_step_time": run.env_time / run.steps,
        "perturbation": run.info.get("perturbation", []),
    }
    return numbers, verdict, replay_record(actions.array(), env.get_sim_state())


def evaluate(
    suite: str,
    tasks: Sequence[int | str] | None,
    policy: Any,
    critic: Any = None,
    config: EvalConfig | None = None,
    *,
    out: str | os.PathLike = "runs/eval",
    resume: bool = False,
    workers: int | Workers = 1,
    progress: bool = True,
    compute: ComputeConfig | None = None,
    **settings: Any,
) -> dict[str, Any]:
    """Evaluate `policy` (a directory or a callable) wrapped in JITI with `critic` (a directory, a critic
    object, or None for modes "base" and "random") on `tasks` of `suite` (None: all).

    The run's settings are `config`'s (default: `EvalConfig`'s defaults), with keyword `settings` naming
    `EvalConfig` or `JITIConfig` fields overriding it (`evaluate(..., mode="base", episodes=50)`); see
    each field's help. `workers`: processes running episodes side by side (`base_suites.runtime.jobs`);
    the numbers do not depend on it, and with more than one the policy and critic must be directories or
    picklable. `compute`: where the BC policy and the critic score (`ComputeConfig`; default: a GPU when
    torch sees one); the run records the kind of device, and resumes only on the same kind.

    Writes the run directory `out` (see the module docstring) and returns the summary dict: config,
    episodes, success_rate, esr, itc_violation_rate (per criterion), interventions_per_episode,
    overrides_per_episode, steps_per_episode, decision_time, env_step_time, decision_overhead, per_task.
    """
    cfg = (config or EvalConfig()).with_settings(**settings)
    device = use_compute(compute or ComputeConfig(), "eval")  # before any work: a GPU that is not there
    check_output(out, "dir", resume=resume, results=("config.json", "episodes.jsonl"))
    if critic is not None and cfg.obs == "rgb":
        raise UserInputError("obs='rgb' has no 'state' for the critic: use obs='both' (or 'lowdim') with a critic")
    specs = task_specs(suite, tasks)
    for spec in specs:
        check_init_states(cfg.init_states, spec.n_init_states)
    starts = min(len(cfg.init_states) if cfg.init_states is not None else spec.n_init_states for spec in specs)
    if cfg.episodes > starts:
        warnings.warn(
            f"{cfg.episodes} episodes per task from {starts} starts: starts repeat, and the intervals and tests "
            "count starts, not episodes",
            RepeatedStartsWarning,
            stacklevel=2,
        )
    indices = list(dict.fromkeys(spec.index for spec in specs))
    workers = check_workers(workers)
    if not workers.in_process:
        check_picklable((policy, critic), "the policy or the critic")
    agent = build_agent(policy, critic, cfg, str(device))
    chosen = None if cfg.init_states is None else sorted({int(i) for i in cfg.init_states})
    described = {
        "policy": describe_policy(policy),
        "policy_act": cfg.policy_act,
        "critic": _describe(critic),
        "jiti": {k: v for k, v in agent.config().items() if k != "mode"},
        "candidate_source": getattr(agent.policy, "candidate_source", "the policy's samples"),
    }
    task_modes = None
    if cfg.gate is not None:
        from elegant.intervention.gate import read_gate

        task_modes = read_gate(cfg.gate, suite, [task_key(suite, i) for i in indices], chosen, described)
    record = {
        "format": RUN_RECORD.tag,
        "suite": suite,
        "tasks": indices,
        **described,
        "mode": cfg.mode,
        "episodes": int(cfg.episodes),
        "seed": int(cfg.seed),
        "perturbation": cfg.perturbation,
        "max_steps": cfg.max_steps,
        "obs": cfg.obs,
        "render_quality": None if cfg.obs == "lowdim" else cfg.render_quality,
        "vla_image_size": cfg.vla_image_size,
        "stack": stack_record(render=None if cfg.obs == "lowdim" else cfg.render_quality),
        "init_states": chosen,
        "device": device_kind(device),
        **({} if cfg.replan_steps is None else {"replan_steps": cfg.replan_steps}),
        **({} if task_modes is None else {"gate": {"file": os.path.abspath(cfg.gate), "modes": task_modes}}),
    }
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with output_lock(out):  # one writer per run directory
        fresh = not (out / "config.json").exists()
        _prepare_run_dir(out, record)
        log = EpisodeLog(out / "episodes.jsonl")
        done = log.done()
        jobs = [
            EvalJob(index, e, cfg.mode if task_modes is None else task_modes[task_key(suite, index)])
            for index in indices
            for e in range(int(cfg.episodes))
            if (task_key(suite, index), e) not in done
        ]
        # the agent built here serves a serial run; worker processes each build their own from the same inputs
        build = partial(build_agent, policy, critic, cfg, str(device))
        make_worker = partial(EpisodeRunner, agent if workers.in_process else build, record)
        try:
            total = len(indices) * int(cfg.episodes)
            with tqdm(
                total=total,
                initial=total - len(jobs),
                desc=" ".join(filter(None, ("eval", cfg.mode, cfg.perturbation))),
                unit="ep",
                disable=not progress,
            ) as bar:
                with run_jobs(make_worker, jobs, workers) as results:
                    for _, (episode, trace) in results:  # only this process writes: workers may be other machines
                        atomic_write(out / episode["trace"], json.dumps(trace))
                        log.append(episode)
                        bar.update(1)
                        bar.set_postfix(
                            success=f"{np.mean([r['success'] for r in log.records]):.2f}",
                            esr=f"{np.mean([r['elegant'] for r in log.records]):.2f}",
                        )
        except UserInputError:
            if fresh and not log.records:  # refused at its first episode (e.g. a critic of other tasks)
                _remove_refused_run(out)
            raise
        ordered = sorted(log.records, key=lambda r: (r.get("task_index", 0), r["task"], int(r["episode"])))
        atomic_write(out / "episodes_sorted.jsonl", "".join(json.dumps(r) + "\n" for r in ordered))
        records = run_records(log.records, record)
        summary = {"config": record, **summarize(records)}
        atomic_write(out / "summary.json", json.dumps(summary, indent=2))
        write_run_report(out, summary, records)
        return summary


@dataclass(frozen=True)
class EvalJob:
    """One episode to run: the task, the episode index and the mode it runs in (the run's mode, or the
    one a gate chose for the task)."""

    task_index: int
    episode: int
    mode: str


class EpisodeRunner:
    """Runs evaluation episodes (`EvalJob`) and returns each one's record and decision trace (the caller
    writes them: a worker may run on another machine).

    Keeps one env with its ITC monitor between episodes of a task (building one costs ~2.5 s). `agent`
    is the JITI-wrapped policy, or a factory that builds it (in a worker process, from directories)."""

    def __init__(self, agent: JITI | Callable[[], JITI], config: Mapping[str, Any]) -> None:
        agent = agent if isinstance(agent, JITI) else agent()
        self._agents = {agent.mode: agent}  # one agent per mode a gate runs tasks in, none changed during the run
        self.config = config
        self._task: int | None = None
        self._env = self._monitor = None

    def __call__(self, job: EvalJob) -> tuple[dict[str, Any], dict[str, Any]]:
        from itc import ITCMonitor

        config, suite = self.config, self.config["suite"]
        if job.task_index != self._task:
            self.close()
            self._env = make_env(
                suite,
                job.task_index,
                seed=config["seed"],
                obs=config["obs"],
                render_quality=config["render_quality"] or "libero",
                vla_image_size=config["vla_image_size"],
                max_steps=config["max_steps"],
                perturbation=config["perturbation"],
            )
            self._monitor, self._task = ITCMonitor(self._env), job.task_index
        env, agent = self._env, self._agent(job.mode)
        init_index, reset_seed = episode_start(
            config["seed"], suite, job.task_index, job.episode, env.task.n_init_states, config["init_states"]
        )
        numbers, verdict, replay = _run_episode(env, agent, self._monitor, init_index, reset_seed)
        record = {
            "task": task_key(suite, job.task_index),
            "suite": suite,
            "task_index": job.task_index,
            "episode": job.episode,
            "init_index": init_index,
            "seed": reset_seed,
            "mode": config["mode"],
            **numbers,
            "trace": f"traces/{trace_name(suite, job.task_index, job.episode)}",
        }
        trace = {
            **{k: record[k] for k in ("task", "episode", "init_index", "mode", "success", "elegant", "violated")},
            "jiti": config["jiti"],
            "segments": {c: np.asarray(v, dtype=bool).tolist() for c, v in verdict.segments.items()},
            "events": [list(e) for e in verdict.events],
            "decisions": agent.trace(),
            "replay": replay,
        }
        return record, trace

    def _agent(self, mode: str) -> JITI:
        """The agent of `mode`: the run's own, or the same policy and critic under a gate's other mode."""
        if mode not in self._agents:
            self._agents[mode] = next(iter(self._agents.values())).with_mode(mode)
        return self._agents[mode]

    def close(self) -> None:
        if self._env is not None:
            self._env.close()
        self._task, self._env, self._monitor = None, None, None


def trace_name(suite: str, task_index: int, episode: int) -> str:
    """File name of an episode's decision log under RUN/traces/."""
    return f"{suite}_{int(task_index)}_{int(episode)}.json"
