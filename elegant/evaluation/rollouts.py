"""Policy rollouts recorded as a dataset, so a critic can learn from the base policy's own mistakes.

A critic trained on demonstrations only knows the demonstrator's ways of failing. A BC policy fails in
its own: on libero_object/0 a policy set the soup can down 3-5 cm off the basket's centre (the limit is
3 cm), which neither the clean expert (within 1.5 cm) nor its `misplace` knob (beside the basket) ever
did, so no demo-trained critic could rank the actions that lead there. Here the policy is rolled out in
the real env, optionally exploring (JITI's mode "random": at a random fraction of its decisions a random
candidate within the trust radius, i.e. the alternatives JITI can choose among), and every episode is
written in the demonstrations' HDF5 layout. `elegant annotate` then labels it like any demo file and
`elegant train-critic` takes demos and rollouts together.

Starts: episode i of a task starts where `elegant eval` episode i would (`episode_start` with the same
seed and `init_states`). To keep an evaluation honest, collect rollouts on init states the evaluation
does not use (`--init-states 0-24` here, `elegant eval --init-states 25-49` there): the env and a
deterministic policy repeat themselves exactly from the same start.

Branches (`explore_at`): the episodes of one start share its reset seed, hence its fixture layout, which
LIBERO draws on every reset and the state does not show (a stove stands up to 2 cm elsewhere). With a
reset seed per episode, one start's branches would differ in that hidden layout as well as in the
explored decision, and a critic could not tell which of the two changed the outcome.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping, Sequence
from functools import partial
from typing import Any

import numpy as np

from annotations.collect import Collection, collect_episodes
from annotations.dataset import DemoFile
from base_suites import task_specs
from base_suites.env import LiberoEnv
from base_suites.runtime.jobs import Workers, check_workers
from base_suites.runtime.outputs import check_output
from base_suites.runtime.seeds import derive_seed
from elegant.evaluation.config import RolloutConfig
from elegant.evaluation.runner import check_init_states, episode_start
from elegant.intervention.jiti import JITI
from elegant.policies.protocol import DEFAULT_POLICY_ACT
from elegant.policies.specs import describe_policy, open_policy


class _PolicySource:
    """`collect_episodes`' actor: the policy wrapped in JITI (mode "base", or "random" to explore)."""

    def __init__(
        self,
        agent: JITI,
        suite: str,
        seed: int,
        init_states: Sequence[int] | None,
        policy_name: str,
        explore_at: Sequence[int] | None,
    ) -> None:
        self.agent, self.suite, self.seed, self.init_states, self.policy_name = (
            agent,
            suite,
            seed,
            init_states,
            policy_name,
        )
        self.explore_at = explore_at

    def for_task(self, env: LiberoEnv, spec: Any) -> None:
        """One JITI serves all tasks (`collect_rollouts` checked the init states up front); only the number of
        starts, which paces the branch points, is per task."""
        self.n_starts = _n_starts(spec, self.init_states)

    def start(self, spec: Any, episode: int) -> tuple[int, int]:
        """Where `elegant eval` episode `episode` starts; with `explore_at`, every branch of a start takes its
        first episode's reset seed too, so the branches share the scene's unobserved fixture layout
        (drawn from the reset seed) and differ in the explored decision only."""
        if self.explore_at is not None:
            episode %= self.n_starts
        return episode_start(self.seed, self.suite, spec.index, episode, spec.n_init_states, self.init_states)

    def begin(self, env: LiberoEnv, episode: int, reset_seed: int) -> None:
        if self.explore_at is None:
            self.agent.reset(env.metadata, seed=reset_seed)
        else:  # branches share the reset seed, not the draw of their explored candidate
            branch = branch_step(self.explore_at, episode, self.n_starts)
            self.agent.reset(env.metadata, seed=derive_seed(reset_seed, episode), random_steps={branch})

    def __call__(self, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        return self.agent(obs)

    def episode_attrs(self) -> dict[str, Any]:
        explored = [d.step for d in self.agent.log if d.chosen != 0]  # not where no candidate was eligible
        return {"policy": self.policy_name, "rollout": self.agent.config(), "explored_steps": explored}


def _policy_source(policy: Any, config: RolloutConfig, suite: str, policy_name: str) -> _PolicySource:
    """The rollouts' actor, built from picklable inputs (a worker process builds its own)."""
    base = open_policy(policy, config.policy_act, replan_steps=config.replan_steps)
    agent = JITI(base, None, config.jiti(), seed=config.seed)
    init_states = None if config.init_states is None else list(config.init_states)
    explore_at = None if config.explore_at is None else list(config.explore_at)
    return _PolicySource(agent, suite, config.seed, init_states, policy_name, explore_at)


def _n_starts(spec: Any, init_states: Sequence[int] | None) -> int:
    """How many starts a task's rollouts cycle through: the chosen init states, or all the task has."""
    return len(init_states) if init_states is not None else spec.n_init_states


def branch_step(explore_at: Sequence[int], episode: int, n_starts: int) -> int:
    """The step whose decision episode `episode` explores, with `--explore-at`: starts cycle first (episode i
    starts from the (i mod n_starts)-th start of the seeded order), then the branch points, so the first
    n_starts * len(explore_at) episodes branch every start once at every point."""
    return int(explore_at[(episode // n_starts) % len(explore_at)])


def branch_points_reached(explore_at: Sequence[int], episodes: int, n_starts: int) -> list[int]:
    """The points of `explore_at` that some of `episodes` branch at. Starts cycle first, so with fewer than
    n_starts * len(explore_at) episodes the later points are never reached, and critics that never saw
    branches late in the episode rank the decisions there worse (docs/lab/jiti-sessions-30-38.md)."""
    return sorted({branch_step(explore_at, e, n_starts) for e in range(episodes)})


def _warn_unreached_points(explore_at: Sequence[int], episodes: int, starts_per_task: Sequence[int]) -> None:
    """One line on stderr when some task's episodes never reach a listed branch point (a likely mistake, not
    an error: files collected that way still resume)."""
    reached = min((branch_points_reached(explore_at, episodes, n) for n in starts_per_task), key=len)
    if len(reached) < len(set(explore_at)):
        needed = max(starts_per_task) * len(explore_at)
        print(
            f"rollouts: warning: {episodes} episodes per task branch only at steps {reached} of --explore-at "
            f"{list(explore_at)}; {needed} would branch every start at every point",
            file=sys.stderr,
        )


def collect_rollouts(
    suite: str,
    tasks: Sequence[int] | None,
    policy: Any,
    out: str,
    config: RolloutConfig | None = None,
    *,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = True,
    workers: int | Workers = 1,
    **settings: Any,
) -> dict[str, Any]:
    """Roll `policy` (a directory or a callable) out on every task of `tasks` of `suite` (None: all of it)
    and write the episodes to `out` (demo layout, crash-safe, resumable with the same settings; `resume` and
    `overwrite` as in `annotations.collect.collect_episodes`).

    The settings are `config`'s (default: `RolloutConfig`'s defaults), with keyword `settings` naming its
    fields overriding it; see each field's help. Without exploration, more episodes than starts repeat
    episodes exactly. `workers`: processes recording episodes side by side; the file does not depend on it.

    Returns: out, episodes, success_rate, explored_per_episode (mean explored decisions).
    """
    cfg = (config or RolloutConfig()).with_settings(**settings)
    check_output(out, "file", resume=resume, overwrite=overwrite)
    specs = task_specs(suite, tasks)
    for spec in specs:
        check_init_states(cfg.init_states, spec.n_init_states)  # before any env or file is made
    if cfg.explore_at is not None:
        _warn_unreached_points(cfg.explore_at, cfg.episodes, [_n_starts(spec, cfg.init_states) for spec in specs])
    name = describe_policy(policy)
    make_source = partial(_policy_source, policy, cfg, suite, name)
    source = make_source()  # here for the settings it records, and to refuse a bad policy before any env is built
    recorded = {
        "policy": name,
        "rollout": source.agent.config(),
        "init_states": source.init_states,
        "max_steps": cfg.max_steps,
    }
    if cfg.explore_at is not None:  # only then: files collected before it existed still resume
        recorded["explore_at"] = list(cfg.explore_at)
        recorded["branches_share_reset_seed"] = True
    if cfg.perturbation:  # likewise
        recorded["perturbation"] = cfg.perturbation
    if cfg.policy_act != DEFAULT_POLICY_ACT:  # likewise
        recorded["policy_act"] = cfg.policy_act
    if cfg.obs != "lowdim":  # likewise
        recorded["obs"] = cfg.obs
        recorded["render_quality"] = cfg.render_quality
    if cfg.vla_image_size is not None:  # likewise
        recorded["vla_image_size"] = cfg.vla_image_size
    rollouts_of = Collection(
        suite,
        tasks,
        cfg.episodes,
        cfg.seed,
        horizon=lambda spec: cfg.max_steps or spec.default_max_steps,
        settings=recorded,
        perturbation=cfg.perturbation,
        obs=cfg.obs,
        render_quality=cfg.render_quality,
        vla_image_size=cfg.vla_image_size,
        desc="rollouts",
    )
    source_of = (lambda: source) if check_workers(workers).in_process else make_source
    path = collect_episodes(
        rollouts_of, out, source_of, resume=resume, overwrite=overwrite, progress=progress, workers=workers
    )
    with DemoFile(path) as f:
        demos = list(f)
    return {
        "out": path,
        "episodes": len(demos),
        "success_rate": float(np.mean([d.attrs["success"] for d in demos])),
        "explored_per_episode": float(np.mean([len(d.attrs.get("explored_steps", [])) for d in demos])),
    }
