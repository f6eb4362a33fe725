"""The whole chain, resumable step by step: the quickstart and the effect benchmark are two sizes of it.

demos (scripted expert, mixed quality, per suite) -> annotate (ITC labels) -> train policy (BC, on every
suite's demos) -> [the policy's own exploring rollouts, annotated] -> train critic (Cal-QL, on every
suite's annotated demos and rollouts) -> evaluate each mode on identical starts, per suite -> side-by-side
report. Each step writes its output atomically and is
skipped when that output already exists, so an interrupted chain continues where it stopped; a chain
directory refuses to continue under other settings.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, replace
from typing import TYPE_CHECKING, Any

from base_suites.runtime.errors import UserInputError, unknown_choice
from base_suites.runtime.io import atomic_write, changed_fields, read_json_file
from elegant.policies.protocol import DEFAULT_POLICY_ACT, POLICY_ACTS

if TYPE_CHECKING:
    from elegant.evaluation.config import EvalConfig

MODES = ("base", "always", "jiti")


@dataclass(frozen=True)
class ChainConfig:
    """Which tasks, how much data and training, which JITI modes to compare.

    The defaults are the chain's first settings, kept so that chain directories written before a field
    existed resume as they ran; the quickstart (`QUICKSTART`) and the benchmark's recipe set their own.

    `tasks` are indices applied to every suite (None: all of each suite's tasks). `critic_gamma` None keeps the
    annotation's discount; 0.9 and a CQL weight of 1 ranked held-out actions better than 0.99 and 5 on
    libero_object/0 (AUROC 0.57 -> 0.64) and keep Q within its feasible range at these data sizes.
    `critic_reward` "segment" (penalise every step of a violating 25-frame window) ranked them better
    than "step" (AUROC 0.72 -> 0.77 on 40 fresh held-out demos, 50 training demos, 2000 steps), and with
    it a CQL weight of 0.2 better than 1 (4000 steps: AUROC 0.79 -> 0.86-0.87 over two seeds).
    `trust_radius`: JITI (and `always`) only pick among candidates within this L2 distance of the base
    action; with a critic trained on a few dozen demos, unrestricted re-ranking chose far-off samples and
    success fell to 0%. `threshold` in units of the running std of Q (2.0):
    on libero_object/0 JITI then intervened 33% as often as `always`. `max_steps` None keeps the
    suites' horizons. `chunk`: actions per decision of the BC policy (executed open-loop) and of the
    critic that judges them; JITI then chooses among whole chunks (see `elegant.intervention.jiti`). `window`: JITI's
    window in decisions (None: JITI's default); `trigger` JITI's critical-moment test (None: JITI's default).
    `policy_modes`: components of the BC policy's GMM head (None: `train_policy`'s default).
    `policy_successful_only`: the policy clones only the demos that succeeded (the critic still sees all).
    `policy_obs_noise`: std of the Gaussian noise on the policy's normalised input states in training.
    `critic_rollouts`: episodes per task of the trained policy, with a random candidate within the trust
    radius at a `rollout_explore` fraction of its decisions (`elegant rollouts`), added to the critic's
    data, so it sees the policy's own mistakes and what its alternatives lead to. The rollouts then start
    from the first half of each task's init states and every evaluation from the second half, so no
    evaluated start was seen in training. `rollout_explore_at`: instead of a rate, the decision steps the
    rollouts branch at, one per episode (`elegant rollouts --explore-at`: episodes from one start then differ
    in one decision, the contrasts a critic must rank; starts cycle first, so `critic_rollouts` should be the
    number of rollout starts times the number of points, or later points are never reached: critics that
    saw branches up to step 144 gained 13 points of ESR on libero_object where those branched up to step 32
    gained 7; on libero_goal 2.6 against 4.8).
    `critic_backup`: the TD target's next action,
    "policy" (Cal-QL's) or "dataset" (in-sample; with the rollouts it values the alternatives they tried).
    `critic_hidden`, `critic_weight_decay`, `critic_mc_weight`, `critic_value_loss` and
    `critic_explored_fraction` are `train_critic`'s `hidden`, `weight_decay`, `mc_weight`, `value_loss`
    and `explored_fraction`: the small regularised outcome classifier of issue 7 (README, `elegant train-critic`)
    is `critic_reward="elegant"`, `critic_value_loss="bce"`, `critic_hidden=(64, 64)`,
    `critic_weight_decay=0.1`, `critic_mc_weight=10`, `critic_explored_fraction=0.5`.
    `critic_members`: with more than one, that many critics are trained, member k on a bootstrap resample
    of the episodes (seed and resample `seed + k`, `train_critic`'s `bootstrap`), into `critic_1` ..
    `critic_K`, and JITI judges with them as a `critics.CriticEnsemble` (every member must prefer an override).
    `max_overrides`: JITI's budget of executed alternatives per episode (None: no limit).
    `warmup`: what JITI's first `window` decisions execute, "base" (the base plan) or "steer" (`JITI`'s `warmup`).
    `candidates`: actions JITI (and `always`) draw from the policy per decision (None: JITI's default, 16).
    `policy_act`: how the BC policy acts in every evaluation (validation too), one of POLICY_ACTS
    (`elegant.policies.bc_policy`: its mixture's most likely mean, a draw, or a drawn component's mean). The
    rollouts for the critic keep the mode, so one critic serves both.
    `jiti_gate`: before the evaluation, the base policy and JITI each run `episodes` per task from the
    rollouts' starts (validation, never the evaluated ones), and JITI is then evaluated only on the tasks
    where it made more episodes elegant than it spoiled there (`elegant.intervention.gate`); needs `critic_rollouts`.
    With "always" among `modes` it is validated too, and the gate may run a task as `always` where that
    did better still, within 40% of `always`'s interventions over the suite.
    """

    suites: tuple[str, ...] = ("libero_object",)
    tasks: tuple[int, ...] | None = (0,)
    demos: int = 50
    quality: str = "mixed"
    critic_steps: int = 1500
    critic_gamma: float | None = 0.9
    critic_cql_weight: float = 0.2
    critic_reward: str = "segment"
    policy_epochs: int = 40
    episodes: int = 6
    modes: tuple[str, ...] = ("base", "jiti")
    seed: int = 0
    trust_radius: float | None = 0.3
    threshold: float | None = 2.0
    threshold_mode: str | None = "std"
    max_steps: int | None = None
    chunk: int = 1
    window: int | None = None
    policy_modes: int | None = None
    policy_successful_only: bool = False
    policy_obs_noise: float = 0.0
    critic_rollouts: int = 0
    rollout_explore: float = 0.3
    critic_backup: str = "policy"
    rollout_explore_at: tuple[int, ...] | None = None
    critic_hidden: tuple[int, ...] = (256, 256)
    critic_weight_decay: float = 0.0
    critic_mc_weight: float = 0.0
    critic_value_loss: str = "mse"
    critic_explored_fraction: float = 0.0
    trigger: str | None = None
    critic_members: int = 1
    max_overrides: int | None = None
    warmup: str | None = None
    jiti_gate: bool = False
    candidates: int | None = None
    policy_act: str = DEFAULT_POLICY_ACT

    def validate(self) -> None:
        unknown = [m for m in self.modes if m not in MODES]
        if unknown or not self.modes:
            raise UserInputError(f"chain modes {list(self.modes)}: expected some of {', '.join(MODES)}")
        for name in ("demos", "critic_steps", "policy_epochs", "episodes", "chunk", "critic_members"):
            if getattr(self, name) < 1:
                raise UserInputError(f"chain {name} must be >= 1, got {getattr(self, name)}")
        if self.policy_modes is not None and self.policy_modes < 1:
            raise UserInputError(f"chain policy_modes must be >= 1, got {self.policy_modes}")
        if not self.policy_obs_noise >= 0:
            raise UserInputError(f"chain policy_obs_noise must be >= 0, got {self.policy_obs_noise}")
        if self.policy_act not in POLICY_ACTS:
            raise unknown_choice("chain policy_act", self.policy_act, POLICY_ACTS)
        if self.critic_rollouts < 0:
            raise UserInputError(f"chain critic_rollouts must be >= 0, got {self.critic_rollouts}")
        if not 0.0 <= self.rollout_explore <= 1.0:
            raise UserInputError(f"chain rollout_explore must lie in [0, 1], got {self.rollout_explore}")
        if not self.suites:
            raise UserInputError("chain suites: give at least one suite")
        if self.rollout_explore_at is not None and (not self.rollout_explore_at or min(self.rollout_explore_at) < 0):
            raise UserInputError(
                f"chain rollout_explore_at must list decision steps >= 0, got {list(self.rollout_explore_at)}"
            )
        from elegant.intervention.config import JITIConfig

        mode = "jiti" if "jiti" in self.modes else "always"
        try:  # JITI's settings, checked by JITI's own rules before hours of demos, not after
            JITIConfig.from_settings(self.jiti_settings(mode), mode=mode)
        except UserInputError as e:
            raise UserInputError(f"chain {e}") from None
        if self.critic_explored_fraction > 0 and not self.critic_rollouts:
            raise UserInputError("chain critic_explored_fraction needs explored decisions: give critic_rollouts > 0")
        if self.jiti_gate and not self.critic_rollouts:
            raise UserInputError(
                "chain jiti_gate validates on the rollouts' starts, apart from the evaluated ones: give "
                "critic_rollouts > 0"
            )
        from critics.config import TrainConfig

        try:  # the critic's settings, checked by the critic's own rules before hours of demos, not after
            TrainConfig(paths=[], **self.critic_settings()).validate()
        except UserInputError as e:
            raise UserInputError(f"chain critic settings: {e}") from None

    def critic_settings(self) -> dict[str, Any]:
        """`train_critic`'s keyword arguments besides the data, the directory and the run controls."""
        return {
            "steps": self.critic_steps,
            "seed": self.seed,
            "gamma": self.critic_gamma,
            "cql_weight": self.critic_cql_weight,
            "reward": self.critic_reward,
            "chunk": self.chunk,
            "backup": self.critic_backup,
            "hidden": list(self.critic_hidden),
            "weight_decay": self.critic_weight_decay,
            "mc_weight": self.critic_mc_weight,
            "value_loss": self.critic_value_loss,
            "explored_fraction": self.critic_explored_fraction,
        }

    def eval_config(self, mode: str, init_states: list[int] | None, gate: str | None = None) -> EvalConfig:
        """How the chain evaluates `mode`: its episodes, seed, horizon and policy act, from `init_states`
        (None: all), with `gate` in mode jiti."""
        from elegant.evaluation.config import EvalConfig

        return EvalConfig(
            episodes=self.episodes,
            seed=self.seed,
            max_steps=self.max_steps,
            policy_act=self.policy_act,
            init_states=None if init_states is None else tuple(init_states),
            gate=gate,
        ).with_settings(mode=mode, **self.jiti_settings(mode))

    def jiti_settings(self, mode: str) -> dict[str, Any]:
        """The JITI settings the chain sets (the others keep `JITIConfig`'s defaults); none for a base run."""
        if mode == "base":
            return {}
        settings = {
            "trust_radius": self.trust_radius,
            "threshold": self.threshold,
            "threshold_mode": self.threshold_mode,
            "window": self.window,
            "trigger": self.trigger,
            "max_overrides": self.max_overrides,
            "warmup": self.warmup,
            "n_candidates": self.candidates,
        }
        return {k: v for k, v in settings.items() if v is not None}


# JITI's recipe (benchmarks/jiti_effect.py, README "Where JITI stands") on one task at small sizes, so the
# first command shows the method as it is evaluated: a chunk-8 BC policy on the successful demos with
# observation noise, branch rollouts of that policy from the first 25 init states, one outcome critic
# (BCE on the elegant-success reward, in-sample backup, small regularised network, half of each batch
# from the explored decisions), and JITI with the drop trigger and a steered warm-up, evaluated on the
# other 25 starts. 100 demos and 300 epochs because the base policy must be worth steering: from 50
# demos and 150 epochs the one-task policy succeeded in 8% of episodes (28% with chunks of 4), from 100
# and 300 in 76%. About 11 minutes on 2 cores. Branch rollouts cycle through the starts first, then the
# branch points (`elegant.evaluation.rollouts.branch_step`): 50 rollouts from 25 starts branch at decisions 8 and 16,
# the first two points of the benchmark's list (whose 100 rollouts per task use its first four).
QUICKSTART = ChainConfig(
    demos=100,
    chunk=8,
    policy_epochs=300,
    policy_successful_only=True,
    policy_obs_noise=0.1,
    critic_rollouts=50,
    rollout_explore_at=(8, 16),
    critic_steps=4000,
    critic_gamma=0.995,
    critic_cql_weight=0.2,
    critic_reward="elegant",
    critic_backup="dataset",
    critic_hidden=(64, 64),
    critic_weight_decay=0.1,
    critic_mc_weight=10.0,
    critic_value_loss="bce",
    critic_explored_fraction=0.5,
    trust_radius=1.5,
    threshold=2.0,
    threshold_mode="std",
    window=4,
    trigger="drop",
    warmup="steer",
    episodes=25,
)

# settings a chain directory may predate
_ADDED_LATER = (
    "chunk",
    "window",
    "policy_successful_only",
    "policy_obs_noise",
    "critic_rollouts",
    "rollout_explore",
    "critic_backup",
    "rollout_explore_at",
    "critic_hidden",
    "critic_weight_decay",
    "critic_mc_weight",
    "critic_value_loss",
    "critic_explored_fraction",
    "trigger",
    "critic_members",
    "max_overrides",
    "warmup",
    "jiti_gate",
    "candidates",
    "policy_act",
)


def _check_settings(out: str, cfg: ChainConfig) -> None:
    path = os.path.join(out, "chain.json")
    settings = json.loads(json.dumps(asdict(cfg)))  # tuples as lists, as stored
    # chains written before these were settings ran as their defaults do; before the mixture size was a
    # setting, policies had 5 components
    defaults = json.loads(json.dumps(asdict(ChainConfig())))
    added = {**{name: defaults[name] for name in _ADDED_LATER}, "policy_modes": 5}
    changed = (
        changed_fields(read_json_file(path, "chain settings"), settings, added=added) if os.path.exists(path) else []
    )
    if changed:
        raise UserInputError(
            f"{path}: {out} holds a chain with other settings ({', '.join(k for k, _, _ in changed)}); choose "
            "another --out"
        )
    atomic_write(path, json.dumps(settings, indent=2))


def _init_split(cfg: ChainConfig) -> tuple[list[int] | None, list[int] | None]:
    """(rollout starts, evaluation starts): the first and second half of the init states every chosen task
    has, when the critic learns from rollouts; (None, None), all starts for the evaluation, otherwise."""
    if not cfg.critic_rollouts:
        return None, None
    from base_suites import task_specs

    specs = [spec for suite in cfg.suites for spec in task_specs(suite, cfg.tasks)]
    shared = min(spec.n_init_states for spec in specs)
    if shared < 2:
        raise UserInputError(
            f"chain critic_rollouts: a task has {shared} init state, too few to keep rollout and evaluation starts "
            "apart"
        )
    return list(range(shared // 2)), list(range(shared // 2, shared))


def _pooled(summaries: list[dict[str, Any]]) -> dict[str, float]:
    """Success, ESR and interventions over several suites' runs, weighted by their episode counts."""
    n = sum(s["episodes"] for s in summaries)
    return {
        k: sum(s[k] * s["episodes"] for s in summaries) / n
        for k in ("success_rate", "esr", "interventions_per_episode")
    }


def run_chain(out: str, config: ChainConfig = QUICKSTART, progress: bool = True, workers: int = 1) -> dict[str, Any]:
    """Run (or continue) the chain in directory `out`, its episodes (demos, annotation replays, rollouts,
    evaluations) on `workers` processes side by side: a run control, not a setting (the numbers do not
    depend on it), so a chain may be continued with another count.

    Returns {mode: pooled success_rate, esr, interventions_per_episode}, per_suite {suite: {mode: the
    same}}, per_task {suite: {mode: the run summary's per-task rows}}, report (the path of the comparison
    markdown), runs ({mode: {suite: run directory}}).
    """
    from annotations import annotate_file
    from annotations.collect import collect_demos
    from critics import train_critic
    from elegant.evaluation.rollouts import collect_rollouts
    from elegant.evaluation.runner import evaluate
    from elegant.intervention.gate import write_gate
    from elegant.policies import train_policy
    from elegant.reporting.report import compare_runs

    cfg = config
    cfg.validate()
    os.makedirs(out, exist_ok=True)
    _check_settings(out, cfg)
    tasks = list(cfg.tasks) if cfg.tasks is not None else None
    demos = {s: os.path.join(out, f"demos_{s}.hdf5") for s in cfg.suites}
    annotated = {s: os.path.join(out, f"annotated_{s}.hdf5") for s in cfg.suites}
    rollouts = {s: os.path.join(out, f"rollouts_{s}.hdf5") for s in cfg.suites}
    annotated_rollouts = {s: os.path.join(out, f"annotated_rollouts_{s}.hdf5") for s in cfg.suites}
    policy_dir = os.path.join(out, "policy")
    members = (
        [{}]
        if cfg.critic_members == 1
        else [{"seed": cfg.seed + k, "bootstrap": cfg.seed + k} for k in range(cfg.critic_members)]
    )
    critic_dirs = [os.path.join(out, "critic" if len(members) == 1 else f"critic_{k + 1}") for k in range(len(members))]
    rollout_starts, eval_starts = _init_split(cfg)
    runs = {m: {s: os.path.join(out, f"eval_{m}_{s}") for s in cfg.suites} for m in cfg.modes}

    def say(step: str) -> None:
        if progress:
            print(f"[chain] {step}", flush=True)

    for suite in cfg.suites:
        if not os.path.exists(demos[suite]):
            say(f"demos: {cfg.demos} {cfg.quality}-quality expert episodes per task of {suite}")
            collect_demos(
                suite,
                tasks,
                cfg.demos,
                demos[suite],
                quality=cfg.quality,
                seed=cfg.seed,
                resume=True,
                progress=progress,
                workers=workers,
            )
        if not os.path.exists(annotated[suite]):
            say(f"annotate {suite}: ITC labels by replaying the demos in the simulator")
            annotate_file(demos[suite], annotated[suite], resume=True, progress=progress, workers=workers)
    if not os.path.exists(os.path.join(policy_dir, "config.json")):
        say(f"train policy: BC with a GMM head, {cfg.policy_epochs} epochs")
        train_policy(
            list(demos.values()),
            policy_dir,
            epochs=cfg.policy_epochs,
            seed=cfg.seed,
            chunk=cfg.chunk,
            resume=True,
            progress=progress,
            successful_only=cfg.policy_successful_only,
            obs_noise=cfg.policy_obs_noise,
            **({} if cfg.policy_modes is None else {"modes": cfg.policy_modes}),
        )
    needs_critic = any(m != "base" for m in cfg.modes)  # base alone (the policy benchmark) only logs its scores
    critic_data = list(annotated.values())
    rollout_suites = cfg.suites if needs_critic and cfg.critic_rollouts else ()
    for suite in rollout_suites:
        if not os.path.exists(rollouts[suite]):
            if cfg.rollout_explore_at is not None:
                explore, how = (
                    {"explore_at": list(cfg.rollout_explore_at)},
                    f"branching at one of steps {list(cfg.rollout_explore_at)}",
                )
            else:
                explore, how = {"explore": cfg.rollout_explore}, f"exploring at {cfg.rollout_explore:.0%} of decisions"
            say(f"rollouts: {cfg.critic_rollouts} episodes per task of {suite}, {how}")
            collect_rollouts(
                suite,
                tasks,
                policy_dir,
                rollouts[suite],
                resume=True,
                progress=progress,
                workers=workers,
                episodes=cfg.critic_rollouts,
                trust_radius=cfg.trust_radius,
                init_states=rollout_starts,
                seed=cfg.seed,
                max_steps=cfg.max_steps,
                **explore,
            )
        if not os.path.exists(annotated_rollouts[suite]):
            say(f"annotate the rollouts of {suite}")
            annotate_file(rollouts[suite], annotated_rollouts[suite], resume=True, progress=progress, workers=workers)
        critic_data.append(annotated_rollouts[suite])
    for k, (critic_dir, member) in enumerate(zip(critic_dirs, members)):
        if needs_critic and not os.path.exists(os.path.join(critic_dir, "critic.json")):
            which = f" member {k + 1} of {len(members)} (bootstrap resample {member['bootstrap']})" if member else ""
            say(f"train critic{which}: Cal-QL, {cfg.critic_steps} steps")
            train_critic(critic_data, critic_dir, **{**cfg.critic_settings(), **member}, resume=True, progress=progress)
    critic = ",".join(critic_dirs) if needs_critic else None
    gates = {s: None for s in cfg.suites}
    if cfg.jiti_gate and "jiti" in cfg.modes:
        validated = ("base", "jiti", *(("always",) if "always" in cfg.modes else ()))
        for suite in cfg.suites:
            say(f"validate {', '.join(validated)} on {suite}'s rollout starts: {cfg.episodes} episodes per task each")
            validation = {}
            for mode in validated:
                validation[mode] = os.path.join(out, f"validate_{mode}_{suite}")
                evaluate(
                    suite,
                    tasks,
                    policy_dir,
                    critic,
                    cfg.eval_config(mode, rollout_starts),
                    out=validation[mode],
                    resume=True,
                    progress=progress,
                    workers=workers,
                )
            gates[suite] = os.path.join(out, f"gate_{suite}.json")
            write_gate(validation["base"], validation["jiti"], gates[suite], always_run=validation.get("always"))
    summaries: dict[str, dict[str, dict[str, Any]]] = {m: {} for m in cfg.modes}
    for mode in cfg.modes:
        for suite in cfg.suites:
            say(f"evaluate {mode} on {suite}: {cfg.episodes} episodes per task")
            summaries[mode][suite] = evaluate(
                suite,
                tasks,
                policy_dir,
                critic,
                cfg.eval_config(mode, eval_starts, gates[suite] if mode == "jiti" else None),
                out=runs[mode][suite],
                resume=True,
                progress=progress,
                workers=workers,
            )
    report_dir = os.path.join(out, "report")
    compare_runs([runs[m][s] for s in cfg.suites for m in cfg.modes], report_dir)
    result: dict[str, Any] = {m: _pooled(list(summaries[m].values())) for m in cfg.modes}
    result["per_suite"] = {s: {m: _pooled([summaries[m][s]]) for m in cfg.modes} for s in cfg.suites}
    result["per_task"] = {s: {m: summaries[m][s]["per_task"] for m in cfg.modes} for s in cfg.suites}
    result["report"] = os.path.join(report_dir, "comparison.md")
    result["runs"] = runs
    return result


def quickstart(
    out: str = "runs/quickstart",
    config: ChainConfig | None = None,
    progress: bool = True,
    workers: int = 1,
    **overrides: Any,
) -> dict[str, Any]:
    """The README's first command: the chain at `QUICKSTART` sizes (fields replaced by `overrides`)."""
    return run_chain(out, replace(config or QUICKSTART, **overrides), progress=progress, workers=workers)
