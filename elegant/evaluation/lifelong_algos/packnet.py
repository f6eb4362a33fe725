"""PackNet: task k trains the free weights only; then the smallest of them are pruned and the rest
fine-tuned, keeping the best fine-tuning checkpoint by success (not counted in the learning curve, as in
LIBERO); task j is evaluated with the weights of tasks 0..j (LIBERO's PackNet)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from base_suites.runtime.errors import UserInputError
from base_suites.runtime.settings import setting
from elegant.evaluation.lifelong_algos import LifelongAlgorithm

if TYPE_CHECKING:
    from elegant.evaluation.lifelong_run import LifelongRun

PACKNET_MASKS_FILE = "packnet_masks.pt"


@dataclass(frozen=True)
class PackNetSettings:
    prune: float = setting(0.75, "PackNet: fraction of a task's weights pruned after it (LIBERO's prune_perc)")
    epochs: int | None = setting(
        None, "PackNet: fine-tuning epochs after pruning (LIBERO's post_prune_epochs; default: --epochs)"
    )


class PackNet(LifelongAlgorithm):
    name = "packnet"
    title = "PackNet"
    position = 3
    Settings = PackNetSettings

    def check(self, settings: PackNetSettings, config: Any) -> None:
        epochs = settings.epochs
        if epochs is not None and (int(epochs) != epochs or epochs < 1):
            raise UserInputError(f"lifelong: packnet_epochs must be a positive integer, got {epochs!r}")
        if epochs is not None and epochs % config.eval_every:
            raise UserInputError(
                f"lifelong: packnet_epochs ({epochs}) must be a multiple of eval_every ({config.eval_every})"
            )
        if not 0 <= settings.prune < 1:
            raise UserInputError(f"lifelong: packnet_prune must be in [0, 1), got {settings.prune!r}")

    def record(self, config: Any) -> dict[str, Any]:
        """Its settings, the fine-tuning epochs defaulting to the protocol's epochs per task."""
        record = super().record(config)
        if record["packnet_epochs"] is None:
            record["packnet_epochs"] = config.epochs
        return record

    def masks_path(self, run: LifelongRun, k: int) -> str:
        return os.path.join(run.stage_dir(k), "pruned", PACKNET_MASKS_FILE)

    def start_task(self, run: LifelongRun, k: int) -> dict[str, Any]:
        from elegant.policies.continual import WeightMasks

        if k == 0:
            return {"masks": WeightMasks({}, 0, claim_free=True)}
        return {"masks": WeightMasks.load(self.masks_path(run, k - 1), k, claim_free=True)}

    def end_task(self, run: LifelongRun, k: int, kept: str) -> tuple[str, Any]:
        from elegant.evaluation.lifelong_run import policy_done, publish_policy
        from elegant.policies.bc_artifact import read_artifact
        from elegant.policies.bc_train import FineTuning, snapshot_dir
        from elegant.policies.continual import WeightMasks

        cfg, settings = run.config, run.settings
        pruned = os.path.join(run.stage_dir(k), "pruned")
        if not policy_done(pruned):
            net, features, artifact = read_artifact(kept)
            masks = self.start_task(run, k)["masks"].bind(net, kept).prune(net, settings.prune)
            os.makedirs(pruned, exist_ok=True)
            masks.save(self.masks_path(run, k))  # before the policy, whose config.json marks the step done
            publish_policy(pruned, net, features, artifact, packnet_pruned_from=os.path.abspath(kept))
        post = os.path.join(run.stage_dir(k), "post")
        post_epochs = list(range(0, settings.epochs + 1, cfg["eval_every"]))
        if not policy_done(post):
            run.status(f"{cfg['task_keys'][k]}: fine-tuning after pruning")
            masks = WeightMasks.load(self.masks_path(run, k), k)
            tune = FineTuning(tasks=[cfg["task_keys"][k]], init_from=pruned, snapshot_epochs=post_epochs, masks=masks)
            run.train(post, tune, settings.epochs, f"{cfg['task_keys'][k]} after pruning")
        rates = [
            run.evaluate(snapshot_dir(post, e), [k], run.out / "evals" / f"task_{k}" / f"post_epoch_{e}")[:, 0]
            for e in post_epochs
        ]
        best = int(np.argmax([r[0] for r in rates]))  # the first best, as LIBERO's strict improvement
        return snapshot_dir(post, post_epochs[best]), rates[best]

    def earlier(self, run: LifelongRun, k: int) -> list[tuple[str, list[int], Path]]:
        from elegant.evaluation.lifelong_run import policy_done, publish_policy
        from elegant.policies.bc_artifact import read_artifact
        from elegant.policies.continual import WeightMasks

        masks = WeightMasks.load(self.masks_path(run, k), k)
        plans = []
        for j in range(k):
            policy = os.path.join(run.stage_dir(k), f"for_task_{j}")
            if not policy_done(policy):
                net, features, artifact = read_artifact(run.kept[k])
                masks.only_tasks_up_to(net, j)
                publish_policy(policy, net, features, artifact, packnet_weights_of_tasks=list(range(j + 1)))
            plans.append((policy, [j], run.out / "evals" / f"after_task_{k}" / f"task_{j}"))
        return plans
