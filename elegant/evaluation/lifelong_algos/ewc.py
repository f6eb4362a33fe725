"""EWC: stage k is penalised towards the network kept after task k-1, weighted by the Fisher information of
tasks 0..k-1, older tasks decayed by gamma per task (LIBERO's EWC)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from base_suites.runtime.errors import UserInputError
from base_suites.runtime.settings import setting
from elegant.evaluation.lifelong_algos import LifelongAlgorithm

if TYPE_CHECKING:
    from elegant.evaluation.lifelong_run import LifelongRun

EWC_ANCHOR_FILE = "ewc_anchor.pt"


@dataclass(frozen=True)
class EWCSettings:
    lambda_: float = setting(5e4, "EWC: weight of the Fisher penalty (LIBERO's e_lambda)")
    gamma: float = setting(0.9, "EWC: decay of earlier tasks' Fisher information per new task (LIBERO's gamma)")


class ElasticWeightConsolidation(LifelongAlgorithm):
    name = "ewc"
    title = "elastic weight consolidation (EWC)"
    position = 2
    Settings = EWCSettings

    def check(self, settings: EWCSettings, config: Any) -> None:
        if not settings.lambda_ >= 0:
            raise UserInputError(f"lifelong: ewc_lambda must be >= 0, got {settings.lambda_!r}")
        if not 0 <= settings.gamma <= 1:
            raise UserInputError(f"lifelong: ewc_gamma must be in [0, 1], got {settings.gamma!r}")

    def anchor_path(self, run: LifelongRun, k: int) -> str:
        return os.path.join(run.stage_dir(k), EWC_ANCHOR_FILE)

    def start_task(self, run: LifelongRun, k: int) -> dict[str, Any]:
        from elegant.policies.continual import ElasticAnchor

        if k == 0:
            return {}
        return {"anchor": ElasticAnchor.load(self.anchor_path(run, k - 1), run.settings.lambda_)}

    def end_task(self, run: LifelongRun, k: int, kept: str) -> tuple[str, Any]:
        from elegant.evaluation.lifelong_run import stage_policy_config
        from elegant.policies.bc_artifact import read_artifact
        from elegant.policies.bc_train import demo_batches, select_tasks
        from elegant.policies.continual import consolidate, fisher_information

        path = self.anchor_path(run, k)
        if not os.path.exists(path):
            run.status(f"{run.config['task_keys'][k]}: Fisher information")
            cfg, settings = run.config, run.settings
            net, features, artifact = read_artifact(kept)
            defaults = stage_policy_config(cfg)
            batches = demo_batches(
                select_tasks(run.data, [cfg["task_keys"][k]]),
                features,
                chunk=defaults.chunk,
                batch_size=defaults.batch_size,
                seed=cfg["seed"] + k,
            )
            previous = None if k == 0 else self.start_task(run, k)["anchor"]
            fisher = fisher_information(net, batches, "cpu")
            consolidate(previous, fisher, net, settings.lambda_, settings.gamma).save(path)
        return kept, None
