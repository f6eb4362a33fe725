"""The BC policy's training settings, torch-free so the CLI builds its options without loading torch.
Each field is also an option of `elegant train-policy` (docs/design.md, configuration). The defaults are
the recommended recipe's base policy (configs/effect.yaml): chunks of 8 actions, trained with observation
noise for 150 epochs."""

from __future__ import annotations

from dataclasses import dataclass

from annotations.features import Encoding
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.settings import check_choices, setting

# Mixture components. LIBERO's GMM baselines use 5; 16 did far better on libero_object/0 (docs/lab/policy.md):
# a joint chunk needs a component per timing of the gripper's close, or it blends them.
DEFAULT_MODES = 16


@dataclass(frozen=True)
class BCConfig:
    """Hyper-parameters of one training run (compared field by field when resuming)."""

    epochs: int = setting(150, "passes over the demos")
    seed: int = setting(0, "network initialisation, batch order and observation noise")
    history: int = setting(10, "states stacked as input")
    batch_size: int = setting(256, "samples per gradient step")
    lr: float = setting(1e-3, "Adam's learning rate (cosine-annealed to 0)")
    weight_decay: float = setting(0.0, "Adam's L2 weight decay")
    hidden: tuple[int, ...] = setting((256, 256), "hidden layer widths, e.g. 256,256")
    modes: int = setting(DEFAULT_MODES, "components of the GMM action head")
    min_std: float = setting(1e-4, "smallest std of a mixture component")
    obs_min_std: float = setting(1e-2, "smallest std of the input normalisation")
    grad_clip: float = setting(100.0, "gradient norm clip")
    chunk: int = setting(8, "actions predicted per decision and executed open-loop (action chunking)")
    task_film: bool = setting(
        True,
        "the task one-hot also modulates every hidden layer (off: it enters at the input only, as policies "
        "before FiLM task conditioning)",
    )
    encoding: Encoding = setting(
        "task-onehot",
        "how a state becomes the policy's input: task-onehot (the trained tasks only) or goal-relative (any "
        "task whose goal it can encode; FiLM then reads the goal's predicates instead of a task one-hot)",
    )
    obs_noise: float = setting(
        0.1,
        "std (normalised units) of Gaussian noise added to input states in training, so the policy learns "
        "to steer back",
    )

    def validate(self) -> None:
        positive = {
            "epochs": self.epochs,
            "history": self.history,
            "batch_size": self.batch_size,
            "modes": self.modes,
            "chunk": self.chunk,
        }
        for name, value in positive.items():
            if int(value) != value or value < 1:
                raise UserInputError(f"train_policy: {name} must be a positive integer, got {value!r}")
        if not self.hidden or any(int(h) != h or h < 1 for h in self.hidden):
            raise UserInputError(f"train_policy: hidden must be positive layer widths, got {self.hidden!r}")
        for name in ("lr", "weight_decay", "grad_clip", "obs_noise"):
            if not getattr(self, name) >= 0:
                raise UserInputError(f"train_policy: {name} must be >= 0, got {getattr(self, name)!r}")
        check_choices(self, "train_policy")
        for name in ("min_std", "obs_min_std"):
            if not getattr(self, name) > 0:
                raise UserInputError(f"train_policy: {name} must be > 0, got {getattr(self, name)!r}")
