"""The chain as a declared list of stages, and the small runner that executes and resumes them
(docs/design.md, data flow).

A `Stage` names what it does (the line the chain prints), the file or directory it leaves when done, and
the call that makes it. The runner skips a stage whose output exists, so an interrupted chain continues
at the first stage that did not finish; a stage without an output (an evaluation, a gate) always runs,
continuing its own episodes. `chain_stages` declares the chain's stages in order for one `ChainConfig`.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from base_suites.runtime.compute import ComputeConfig
from base_suites.runtime.jobs import Workers
from elegant.chain_config import ChainConfig


@dataclass(frozen=True)
class Stage:
    """One step of the chain: `run()` makes `done` (None: the stage runs every time, resuming itself)."""

    name: str
    says: str
    done: str | None
    run: Callable[[], Any]


def run_stages(stages: Sequence[Stage], say: Callable[[str], None]) -> dict[str, Any]:
    """Run each stage whose output does not exist yet, in order; returns {name: what its run returned}."""
    results = {}
    for stage in stages:
        if stage.done is not None and os.path.exists(stage.done):
            continue
        say(stage.says)
        results[stage.name] = stage.run()
    return results


@dataclass(frozen=True)
class ChainPaths:
    """Where each stage of a chain in `out` writes."""

    out: str
    suites: tuple[str, ...]
    modes: tuple[str, ...]
    critic_members: int

    def demos(self, suite: str) -> str:
        return os.path.join(self.out, f"demos_{suite}.hdf5")

    def annotated(self, suite: str) -> str:
        return os.path.join(self.out, f"annotated_{suite}.hdf5")

    def rollouts(self, suite: str) -> str:
        return os.path.join(self.out, f"rollouts_{suite}.hdf5")

    def annotated_rollouts(self, suite: str) -> str:
        return os.path.join(self.out, f"annotated_rollouts_{suite}.hdf5")

    @property
    def policy(self) -> str:
        return os.path.join(self.out, "policy")

    @property
    def critics(self) -> list[str]:
        if self.critic_members == 1:
            return [os.path.join(self.out, "critic")]
        return [os.path.join(self.out, f"critic_{k + 1}") for k in range(self.critic_members)]

    def validation(self, mode: str, suite: str) -> str:
        return os.path.join(self.out, f"validate_{mode}_{suite}")

    def gate(self, suite: str) -> str:
        return os.path.join(self.out, f"gate_{suite}.json")

    def run(self, mode: str, suite: str) -> str:
        return os.path.join(self.out, f"eval_{mode}_{suite}")

    @property
    def runs(self) -> dict[str, dict[str, str]]:
        """{mode: {suite: run directory}}."""
        return {m: {s: self.run(m, s) for s in self.suites} for m in self.modes}


def chain_stages(
    paths: ChainPaths,
    cfg: ChainConfig,
    starts: tuple[list[int] | None, list[int] | None],
    *,
    progress: bool,
    workers: int | Workers,
    compute: ComputeConfig,
) -> list[Stage]:
    """The chain's stages in order: per suite demos and their annotation; the policy; with a critic, per
    suite the policy's rollouts and their annotation, then each critic member; with the gate, per suite
    the validation runs and the gate; then every mode's evaluation per suite. `starts` is
    (rollout starts, evaluation starts) (`init_split`)."""
    from annotations import annotate_file
    from annotations.collect import collect_demos
    from critics import train_critic
    from elegant.evaluation.rollouts import collect_rollouts
    from elegant.evaluation.runner import evaluate
    from elegant.intervention.gate import write_gate
    from elegant.policies import train_policy

    tasks = list(cfg.tasks) if cfg.tasks is not None else None
    rollout_starts, eval_starts = starts
    controls = {"resume": True, "progress": progress, "workers": workers}
    stages: list[Stage] = []
    for suite in cfg.suites:
        stages += [
            Stage(
                f"demos {suite}",
                f"demos: {cfg.demos} {cfg.quality}-quality expert episodes per task of {suite}",
                paths.demos(suite),
                lambda suite=suite: collect_demos(
                    suite, tasks, paths.demos(suite), **controls, episodes=cfg.demos, quality=cfg.quality, seed=cfg.seed
                ),
            ),
            Stage(
                f"annotate {suite}",
                f"annotate {suite}: ITC labels by replaying the demos in the simulator",
                paths.annotated(suite),
                lambda suite=suite: annotate_file(paths.demos(suite), paths.annotated(suite), **controls),
            ),
        ]
    stages.append(
        Stage(
            "policy",
            f"train policy: BC with a GMM head, {cfg.policy.epochs} epochs",
            os.path.join(paths.policy, "config.json"),
            lambda: train_policy(
                [paths.demos(s) for s in cfg.suites],
                paths.policy,
                cfg.policy_config(),
                successful_only=cfg.successful_only,
                resume=True,
                progress=progress,
                compute=compute,
            ),
        )
    )
    critic_data = [paths.annotated(s) for s in cfg.suites]
    if cfg.needs_critic() and cfg.critic_rollouts:
        recording = cfg.rollout_config(rollout_starts)
        if recording.explore_at is not None:
            how = f"branching at one of steps {list(recording.explore_at)}"
        else:
            how = f"exploring at {recording.explore:.0%} of decisions"
        for suite in cfg.suites:
            stages += [
                Stage(
                    f"rollouts {suite}",
                    f"rollouts: {cfg.critic_rollouts} episodes per task of {suite}, {how}",
                    paths.rollouts(suite),
                    lambda suite=suite: collect_rollouts(
                        suite, tasks, paths.policy, paths.rollouts(suite), recording, **controls
                    ),
                ),
                Stage(
                    f"annotate rollouts {suite}",
                    f"annotate the rollouts of {suite}",
                    paths.annotated_rollouts(suite),
                    lambda suite=suite: annotate_file(
                        paths.rollouts(suite), paths.annotated_rollouts(suite), **controls
                    ),
                ),
            ]
        critic_data += [paths.annotated_rollouts(s) for s in cfg.suites]
    if cfg.needs_critic():
        members = paths.critics
        for k, critic_dir in enumerate(members):
            training = cfg.critic_config(k)
            which = (
                f" member {k + 1} of {len(members)} (bootstrap resample {training.bootstrap})"
                if len(members) > 1
                else ""
            )
            stages.append(
                Stage(
                    f"critic {k + 1}",
                    f"train critic{which}: Cal-QL, {training.steps} steps",
                    os.path.join(critic_dir, "critic.json"),
                    lambda critic_dir=critic_dir, training=training: train_critic(
                        critic_data, critic_dir, training, resume=True, progress=progress, compute=compute
                    ),
                )
            )
    critic = ",".join(paths.critics) if cfg.needs_critic() else None
    evaluation = {"resume": True, "progress": progress, "workers": workers, "compute": compute}
    validated = cfg.validated_modes()

    def validate_and_gate(suite: str) -> str:
        for mode in validated:
            config = cfg.eval_config(mode, rollout_starts)
            evaluate(suite, tasks, paths.policy, critic, config, out=paths.validation(mode, suite), **evaluation)
        # derived again from the same validation runs on every resume: the same file
        always = paths.validation("always", suite) if "always" in validated else None
        base, jiti = paths.validation("base", suite), paths.validation("jiti", suite)
        write_gate(base, jiti, paths.gate(suite), always_run=always, overwrite=True)
        return paths.gate(suite)

    if validated:
        for suite in cfg.suites:
            stages.append(
                Stage(
                    f"gate {suite}",
                    f"validate {', '.join(validated)} on {suite}'s rollout starts: {cfg.evaluation.episodes} episodes "
                    "per task each",
                    None,
                    lambda suite=suite: validate_and_gate(suite),
                )
            )
    for mode in cfg.modes:
        for suite in cfg.suites:
            gate = paths.gate(suite) if validated and mode == "jiti" else None
            stages.append(
                Stage(
                    f"eval {mode} {suite}",
                    f"evaluate {mode} on {suite}: {cfg.evaluation.episodes} episodes per task",
                    None,
                    lambda mode=mode, suite=suite, gate=gate: evaluate(
                        suite,
                        tasks,
                        paths.policy,
                        critic,
                        cfg.eval_config(mode, eval_starts, gate),
                        out=paths.run(mode, suite),
                        **evaluation,
                    ),
                )
            )
    return stages
