"""The critic's settings, torch-free so the CLI can build its options without loading torch: the reward,
backup and value-loss choices, and `TrainConfig`, everything that determines a trained critic."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

from annotations.features import Encoding
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.settings import check_choices, setting

# the violation penalty per step or per window; or an elegant success (`critics.data.load_transitions`)
Reward = Literal["step", "segment", "elegant"]
REWARDS: tuple[str, ...] = get_args(Reward)
# the next action of the TD target: a' ~ pi(.|s'), or the dataset's (`critics.loss.CalQLLoss`)
Backup = Literal["policy", "dataset"]
BACKUPS: tuple[str, ...] = get_args(Backup)
# Q regressed on its target, or Q a logit classified against a target probability
ValueLoss = Literal["mse", "bce"]
VALUE_LOSSES: tuple[str, ...] = get_args(ValueLoss)


@dataclass(frozen=True)
class TrainConfig:
    """Everything that determines the trained numbers (saved in the checkpoint and the artifact); each
    field is also an option of `elegant train-critic`. The defaults are the recommended recipe's outcome
    critic (configs/effect.yaml), apart from `explored_fraction`, which needs explored rollouts."""

    paths: list[str] = setting(help="annotated HDF5 files, all with the same gamma", factory=list)
    steps: int = setting(4000, "gradient steps in all (a resumed run continues up to it)")
    batch_size: int = setting(256, "transitions per step")
    seed: int = setting(0, "network initialisation, replay sampling and action draws")
    n_actions: int = setting(10, "sampled actions per state for the CQL term (uniform, pi(.|s), pi(.|s'))")
    hidden: list[int] = setting(
        help="hidden layer widths of the critics and the actor, e.g. 64,64", factory=lambda: [64, 64]
    )
    cql_weight: float = setting(0.2, "weight of the CQL term")
    temperature: float = setting(1.0, "the CQL logsumexp's temperature")
    calibrate: bool = setting(True, "clip Q(s, a~pi) from below by the Monte-Carlo return (Cal-QL; off: plain CQL)")
    with_lagrange: bool = setting(False, "tune the CQL weight with a Lagrange multiplier", flag="--lagrange")
    target_action_gap: float = setting(0.8, "the Lagrange target of the CQL gap (with --lagrange)")
    critic_lr: float = setting(3e-4, "the critics' learning rate")
    actor_lr: float = setting(1e-4, "the actor's learning rate")
    alpha_lr: float = setting(3e-4, "the temperature's learning rate")
    tau: float = setting(0.005, "soft update rate of the target critics")
    log_every: int = setting(100, "steps between rows of metrics.csv")
    checkpoint_every: int = setting(1000, "steps between checkpoints")
    gamma: float | None = setting(0.995, "the critic's discount (None: the annotation's)")
    reward: Reward = setting(
        "elegant",
        "step: penalise each violating step; segment: every step of a violating 25-frame window; "
        "elegant: 1 for an elegant success, the episode ending at its first violating window",
    )
    chunk: int = setting(8, "actions per scored decision (the chunk length of the policy to judge)")
    backup: Backup = setting(
        "dataset", "the TD target's next action: policy (a' ~ pi, Cal-QL's) or dataset (the demo's next action)"
    )
    weight_decay: float = setting(0.1, "decoupled weight decay of the critics' weights (not the actor's)")
    mc_weight: float = setting(10.0, "weight of Q's regression on the Monte-Carlo returns beside TD")
    value_loss: ValueLoss = setting(
        "bce", "mse, or bce (with --reward elegant): logits fitted to the target probability by cross-entropy"
    )
    explored_fraction: float = setting(
        0.0, "share of each batch drawn from explored decisions (rollouts' explored_steps); the recipe: 0.5"
    )
    tasks: tuple[str, ...] | None = setting(
        None,
        "train on the demos of these tasks only, e.g. libero_object/0,libero_object/1 (default: every task in "
        "the files): a goal-relative critic then scores the others unseen",
    )
    encoding: Encoding = setting(
        "task-onehot",
        "how a state becomes the critic's input: task-onehot (padded state and task one-hot: the trained "
        "tasks only) or goal-relative (the state read through the episode's goal: any task it can encode)",
    )
    bootstrap: int | None = setting(
        None,
        "train on a bootstrap resample of the episodes drawn with this seed: one member of a critic "
        "ensemble (pass the members' directories comma-separated to eval --critic)",
        metavar="SEED",
    )

    @property
    def explored_per_batch(self) -> int:
        return round(self.batch_size * self.explored_fraction)

    def validate(self) -> None:
        for name in ("steps", "batch_size", "n_actions", "log_every", "checkpoint_every", "chunk"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise UserInputError(f"train-critic: {name} must be a positive integer, got {value!r}")
        if not self.hidden or any(int(h) < 1 for h in self.hidden):
            raise UserInputError(f"train-critic: hidden must list positive layer widths, got {self.hidden!r}")
        if self.gamma is not None and not 0.0 < self.gamma < 1.0:
            raise UserInputError(f"train-critic: gamma must lie in (0, 1), got {self.gamma}")
        check_choices(self, "train-critic")
        if self.value_loss == "bce" and self.reward != "elegant":
            raise UserInputError(
                "train-critic: value_loss 'bce' needs returns in [0, 1], i.e. reward 'elegant' (got reward "
                f"{self.reward!r})"
            )
        for name in ("weight_decay", "mc_weight"):
            if not getattr(self, name) >= 0.0:
                raise UserInputError(f"train-critic: {name} must be >= 0, got {getattr(self, name)}")
        if not 0.0 <= self.explored_fraction < 1.0 or (
            self.explored_fraction > 0 and not 0 < self.explored_per_batch < self.batch_size
        ):
            raise UserInputError(
                "train-critic: explored_fraction must lie in [0, 1) and leave at least one row of each kind in a "
                "batch "
                f"of {self.batch_size}, got {self.explored_fraction}"
            )
