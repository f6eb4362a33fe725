"""Episode collection in the real env, written as LIBERO-layout HDF5: scripted-expert demonstrations here,
policy rollouts (`elegant.evaluation.rollouts`) through the same `collect_episodes`.

A demo collection's episode i of a task starts from shipped init state i (mod 50), and its quality
knobs come from (seed, task, i), so a collection interrupted and resumed produces exactly the file an
uninterrupted run would have.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any, Protocol

import numpy as np

from annotations.dataset import Demo, DemoFile, DemoWriter
from base_suites import make_env, task_specs
from base_suites.env import LiberoEnv
from base_suites.experts import EXPERT_VERSION, ScriptedExpert, knob_rates, parse_quality
from base_suites.rollout import StepObserver, run_episode
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import changed_fields
from base_suites.runtime.jobs import Workers, check_picklable, check_workers, in_order, run_jobs
from base_suites.runtime.outputs import check_output
from base_suites.runtime.seeds import derive_seed
from base_suites.runtime.settings import setting, with_overrides

DEMO_HORIZON_FACTOR = 2


def dataset_attrs(env: LiberoEnv, suite: str, tasks: Sequence[int]) -> dict[str, Any]:
    """The `data` group attributes, in LIBERO's robomimic style."""
    domain = env.domain
    return {
        "env_args": {
            "env_name": "libero",
            "type": 1,
            "env_kwargs": {
                "suite": suite,
                "tasks": list(tasks),
                "controller": "OSC_POSE",
                "control_freq": 20,
                "settle_steps": env.settle_steps,
                "obs": "lowdim",
                "hard_reset": False,
            },
        },
        "problem_info": {
            "problem_name": type(domain).__name__.lower(),
            "domain_name": "robosuite",
            "language_instruction": env.instruction,
        },
        "language_instruction": env.instruction,
        "bddl_file_name": env.task.bddl_file,
    }


class EpisodeSource(Protocol):
    """What `collect_episodes` rolls out: per task, an actor for its episodes and where each one starts.

    Each worker process builds its own source from the factory it is given and sees only some of the
    episodes, in any order, so an episode must depend on its task and index alone: `begin` restarts all
    of the actor's randomness from them, and `for_task` may be called again for a task seen before."""

    def for_task(self, env: LiberoEnv, spec: Any) -> None:
        """Get ready for the episodes of one task (its env is built)."""

    def start(self, spec: Any, episode: int) -> tuple[int, int]:
        """(init-state index, env reset seed) of an episode: a function of the episode, so resuming rebuilds it."""

    def begin(self, env: LiberoEnv, episode: int, reset_seed: int) -> None:
        """Reset the actor for an episode (the env has just been reset)."""

    def __call__(self, obs: Mapping[str, np.ndarray]) -> np.ndarray: ...

    def episode_attrs(self) -> dict[str, Any]:
        """Attributes to store with the finished episode (knobs, policy settings, ...)."""


@dataclass(frozen=True)
class Collection:
    """Which episodes a recorded file holds and what determines them: `episodes` per task of `tasks` of
    `suite` (None: every task), from `seed`; `horizon(spec)` is each task's episode limit; `perturbation`
    (e.g. "init@nudge") is applied to every env; `obs` is the envs' observation mode (what the source sees;
    the file stores the state whatever it is), `render_quality` and `vla_image_size` how its images are made; `settings`
    (what else determines the episodes) is stored in the file's `collection` attribute, and a resumed file
    must match it. `desc` labels the progress bar."""

    suite: str
    tasks: Sequence[int] | None
    episodes: int
    seed: int
    horizon: Callable[[Any], int]
    settings: Mapping[str, Any]
    perturbation: str | None = None
    obs: str = "lowdim"
    render_quality: str = "libero"
    vla_image_size: int | None = None
    desc: str = "episodes"


def collect_episodes(
    collection: Collection,
    out: str,
    make_source: Callable[[], EpisodeSource],
    *,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = True,
    workers: int | Workers = 1,
) -> str:
    """Roll the source `make_source()` builds out as `collection` says and write the episodes to `out` in
        the demo layout: appended to `out.partial` in episode order as they finish, renamed to `out` when all
        are there; `resume` continues an interrupted file, only with the same collection (a finished one is
    returned as it is), and `overwrite` replaces an existing file once the new one is complete. `workers`: processes
        recording episodes side by side (`base_suites.runtime.jobs`; `make_source` must then be picklable);
        the file does not depend on it. Returns the path."""
    from tqdm import tqdm

    suite, tasks, episodes, seed = collection.suite, collection.tasks, collection.episodes, collection.seed
    horizon, settings, perturbation, desc = (
        collection.horizon,
        collection.settings,
        collection.perturbation,
        collection.desc,
    )
    images = {
        "obs": collection.obs,
        "render_quality": collection.render_quality,
        "vla_image_size": collection.vla_image_size,
    }
    check_output(out, "file", resume=resume, overwrite=overwrite)
    if episodes <= 0:
        raise UserInputError(f"--episodes must be positive, got {episodes}")
    workers = check_workers(workers)
    if not workers.in_process:
        check_picklable(make_source, "the policy or expert of these episodes")
    specs = task_specs(suite, tasks)
    collection = json.loads(
        json.dumps({"suite": suite, "tasks": [s.index for s in specs], "episodes": episodes, "seed": seed, **settings})
    )
    if resume and os.path.exists(out) and not DemoWriter.resumable(out):
        return _finished(out, collection)
    writer = DemoWriter(
        out, _file_attrs(out, resume, suite, specs, seed, horizon, perturbation, collection), resume=resume
    )
    bar = None
    try:
        # the episode count too: demo_<i> is episode i mod episodes of task i // episodes
        changed = changed_fields(writer.attrs.get("collection"), collection)
        if changed:
            raise UserInputError(
                f"{out}.partial: cannot resume with different {', '.join(k for k, _, _ in changed)}; "
                "delete it or collect with its settings"
            )
        done_before = writer.count
        jobs = [
            EpisodeJob(pos * episodes + i, spec.index, i)
            for pos, spec in enumerate(specs)
            for i in range(episodes)
            if pos * episodes + i >= done_before
        ]
        recorder = partial(
            EpisodeRecorder,
            make_source,
            suite,
            seed,
            {s.index: horizon(s) for s in specs},
            perturbation,
            images,
        )
        bar = tqdm(
            total=len(specs) * episodes, initial=done_before, desc=f"{desc} {suite}", disable=not progress, unit="ep"
        )
        with run_jobs(recorder, jobs, workers) as results:
            for _, (demo, layout) in in_order(results, lambda job: job.position, first=done_before):
                writer.append(demo, layout)
                bar.update(1)
        return writer.finish()
    except BaseException:
        writer.abandon()
        raise
    finally:
        if bar is not None:
            bar.close()


def _finished(out: str, collection: Mapping[str, Any]) -> str:
    """A finished file that `--resume` finds: returned as it is when it holds this collection."""
    with DemoFile(out) as done:
        changed = changed_fields(done.attrs.get("collection"), collection)
    if changed:
        raise UserInputError(
            f"{out}: a finished file of different {', '.join(k for k, _, _ in changed)}; "
            "choose another path or pass --overwrite"
        )
    return out


def _file_attrs(
    out: str,
    resume: bool,
    suite: str,
    specs: Sequence[Any],
    seed: int,
    horizon: Callable[[Any], int],
    perturbation: str | None,
    collection: Mapping[str, Any],
) -> dict[str, Any]:
    """The new file's `data` attributes, read off the first task's env; none when an interrupted file is
    resumed (it keeps its own), so a resume builds no env before its settings are checked."""
    if resume and DemoWriter.resumable(out):
        return {}
    env = make_env(suite, specs[0].index, seed=seed, max_steps=horizon(specs[0]), perturbation=perturbation)
    try:
        return {**dataset_attrs(env, suite, [s.index for s in specs]), "collection": collection}
    finally:
        env.close()


@dataclass(frozen=True)
class EpisodeJob:
    """One episode to record: its place in the file (demo_<position>), its task and its index within the task."""

    position: int
    task_index: int
    episode: int


class EpisodeRecorder:
    """Records episodes (`EpisodeJob`) of one source, keeping one env between the episodes of a task
    (building one costs ~2.5 s); returns each as a `Demo` with its env's state layout."""

    def __init__(
        self,
        make_source: Callable[[], EpisodeSource],
        suite: str,
        seed: int,
        horizons: Mapping[int, int],
        perturbation: str | None,
        images: Mapping[str, Any] | None = None,
    ) -> None:
        self.source, self.suite, self.seed, self.horizons, self.perturbation = (
            make_source(),
            suite,
            seed,
            horizons,
            perturbation,
        )
        self.images = dict(images or {})  # make_env's obs, render_quality and vla_image_size
        self._env: LiberoEnv | None = None
        self._spec: Any = None

    def __call__(self, job: EpisodeJob) -> tuple[Demo, list]:
        if self._spec is None or self._spec.index != job.task_index:
            self.close()
            self._spec = task_specs(self.suite, [job.task_index])[0]
            self._env = make_env(
                self.suite,
                job.task_index,
                seed=self.seed,
                max_steps=self.horizons[job.task_index],
                perturbation=self.perturbation,
                **self.images,
            )
            self.source.for_task(self._env, self._spec)
        env, spec, source = self._env, self._spec, self.source
        init, reset_seed = source.start(spec, job.episode)
        obs, _ = env.reset(seed=reset_seed, options={"init_state": init})
        layout, geometry = env.fixture_layout(), env.metadata["goal_geometry"]
        source.begin(env, job.episode, reset_seed)
        record = record_episode(env, source, obs)
        demo = Demo(
            name="",
            actions=record["actions"],
            states=record["states"],
            obs=record["obs"],
            next_obs=record["next_obs"],
            rewards=record["rewards"],
            dones=record["dones"],
            final_state=record["final_state"],
            attrs={
                "suite": self.suite,
                "task_index": spec.index,
                "task_name": spec.name,
                "language_instruction": env.instruction,
                "init_state_index": init,
                "seed": self.seed,
                "episode": job.episode,
                "success": record["success"],
                "perturbation": record["perturbation"],
                "reset_seed": reset_seed,
                "fixture_layout": layout,
                "goal_geometry": geometry,
                **source.episode_attrs(),
            },
        )
        return demo, env.metadata["state_layout"]

    def close(self) -> None:
        if self._env is not None:
            self._env.close()
        self._env, self._spec = None, None


class _ExpertSource:
    """The scripted expert: episode i starts from init state i (mod 50), knobs from (seed, task, i)."""

    def __init__(self, quality: str | Mapping[str, float], seed: int) -> None:
        self.quality, self.seed = quality, seed

    def for_task(self, env: LiberoEnv, spec: Any) -> None:
        self.expert = ScriptedExpert(env, quality=self.quality, seed=derive_seed(self.seed, spec.index))

    def start(self, spec: Any, episode: int) -> tuple[int, int]:
        # A reset seed per (seed, task, episode): a resumed collection rebuilds the same scenes.
        return episode % spec.n_init_states, derive_seed(self.seed, spec.index, episode)

    def begin(self, env: LiberoEnv, episode: int, reset_seed: int) -> None:
        self.expert.reset(env.metadata, episode=episode)

    def __call__(self, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        return self.expert(obs)

    def episode_attrs(self) -> dict[str, Any]:
        return {
            "knobs": dict(self.expert.knobs),
            "knob_events": list(self.expert.events),
            "expert_version": EXPERT_VERSION,
        }


@dataclass(frozen=True)
class DemoConfig:
    """What `elegant demos` records: the scripted expert's episodes per task, their execution quality (a
    preset or knob probabilities, stored per episode in its `knobs` attribute) and the seed."""

    episodes: int = setting(50, "episodes per task")
    quality: str | Mapping[str, float] = setting(
        "clean",
        "clean, mixed, or knob=prob,... (knobs: collide, drop, misplace, tilt, wrong_order, jerky, regrasp)",
        parse=parse_quality,
    )
    seed: int = setting(0, "the expert's and the scenes' seed")

    def __post_init__(self) -> None:
        if not int(self.episodes) >= 1:
            raise UserInputError(f"demos: episodes must be >= 1, got {self.episodes}")
        if not int(self.seed) >= 0:
            raise UserInputError(f"demos: seed must be >= 0, got {self.seed}")
        knob_rates(self.quality)


def collect_demos(
    suite: str,
    tasks: Sequence[int] | None,
    out: str,
    config: DemoConfig | None = None,
    *,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = True,
    workers: int | Workers = 1,
    **settings: Any,
) -> dict[str, Any]:
    """Roll out the scripted expert on every task of `tasks` of `suite` (None: all) as `config` says
    (default: `DemoConfig`'s defaults; keyword `settings` override its fields) and write the demos file
    `out` (`workers` processes side by side; the file does not depend on it; `resume` and `overwrite` as in
    `collect_episodes`).

    Returns a summary: demos written, success rate, per-knob rates, per-task success.
    """
    cfg = with_overrides(config or DemoConfig(), settings, "demos")
    episodes, quality, seed = cfg.episodes, cfg.quality, cfg.seed
    # Demos may run longer than the evaluation horizon: sloppy executions (undo, regrasp) take time.
    demos_of = Collection(
        suite,
        tasks,
        episodes,
        seed,
        horizon=lambda spec: DEMO_HORIZON_FACTOR * spec.default_max_steps,
        settings={"quality": quality},
        desc="demos",
    )
    path = collect_episodes(
        demos_of,
        out,
        partial(_ExpertSource, quality, seed),
        resume=resume,
        overwrite=overwrite,
        progress=progress,
        workers=workers,
    )
    from annotations.dataset import DemoFile

    with DemoFile(path) as f:
        demos = list(f)
    knobs = [d.attrs["knobs"] for d in demos]
    summary: dict[str, Any] = {"out": out, "per_task": {}}
    summary.update(
        demos=len(demos),
        success_rate=float(np.mean([d.attrs["success"] for d in demos])),
        knob_rates={k: float(np.mean([kn.get(k, False) for kn in knobs])) for k in (knobs[0] if knobs else {})},
    )
    for d in demos:
        summary["per_task"].setdefault(d.task_key, []).append(bool(d.attrs["success"]))
    summary["per_task"] = {k: float(np.mean(v)) for k, v in summary["per_task"].items()}
    return summary


class EpisodeRecording(StepObserver):
    """Records what the demo format stores of an episode: the simulator state and observation before each
    step, the executed action, the next observation and the reward."""

    def __init__(self) -> None:
        self.states: list[np.ndarray] = []
        self.obs: list[np.ndarray] = []
        self.next_obs: list[np.ndarray] = []
        self.actions: list[np.ndarray] = []
        self.rewards: list[float] = []

    def before_step(self, env: LiberoEnv, obs: Mapping[str, np.ndarray]) -> None:
        self.states.append(env.get_sim_state())
        self.obs.append(obs["state"])

    def after_step(
        self, env: LiberoEnv, action: np.ndarray, obs: Mapping[str, np.ndarray], reward: float, info: Mapping[str, Any]
    ) -> bool:
        self.actions.append(action)
        self.next_obs.append(obs["state"])
        self.rewards.append(reward)
        return False


def record_episode(env: LiberoEnv, policy, obs: Mapping[str, np.ndarray]) -> dict[str, Any]:
    """Run `policy` from the env's just-reset state (`base_suites.rollout.run_episode`) and return what the
    demo format stores."""
    recording = EpisodeRecording()
    run = run_episode(env, policy, obs, [recording])
    dones = np.zeros(run.steps, dtype=np.uint8)
    dones[-1] = 1
    return {
        "actions": np.array(recording.actions),
        "states": np.array(recording.states),
        "obs": np.array(recording.obs),
        "next_obs": np.array(recording.next_obs),
        "rewards": np.array(recording.rewards, dtype=np.float32),
        "dones": dones,
        "success": bool(run.info["success"]),
        "perturbation": run.info["perturbation"],
        "final_state": env.get_sim_state(),
    }
