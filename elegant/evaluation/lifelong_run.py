"""What every stage of `elegant lifelong` shares (docs/design.md §8.3): the run's settings, demos, fixed
input features and the networks kept so far (`LifelongRun`), the stage policy's config, and publishing a
derived policy. The algorithms themselves are registered classes, one module each, in
`elegant.evaluation.lifelong_algos`.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from base_suites.runtime.compute import ComputeConfig
from base_suites.runtime.io import read_json_file
from base_suites.runtime.jobs import Workers
from elegant.evaluation.runner import evaluate
from elegant.policies.bc_artifact import write_artifact
from elegant.policies.bc_config import BCConfig
from elegant.policies.bc_data import DemoSet
from elegant.policies.bc_features import BCFeatures
from elegant.policies.bc_train import FineTuning, train_policy


def stage_policy_config(config: dict[str, Any], epochs: int | None = None) -> BCConfig:
    """The policy every stage of the run recorded in `config` trains (for `epochs`, default the run's):
    LIBERO's lifelong protocol clones one action per step, without input noise, in small batches (the
    chunked, noise-trained policy of JITI's recipe is another experiment)."""
    return BCConfig(
        epochs=config["epochs"] if epochs is None else epochs,
        seed=config["seed"],
        modes=config["modes"],
        batch_size=config["batch_size"],
        encoding=config["encoding"],
        chunk=1,
        obs_noise=0.0,
    )


@dataclass
class LifelongRun:
    """What every stage needs: the settings, the demos, the fixed input features and the networks kept so far."""

    out: Path
    config: dict[str, Any]
    paths: list[str]
    data: DemoSet
    features: BCFeatures
    status: Callable[[str], None]
    workers: int | Workers = 1  # processes per evaluation (a run control, not a setting: results do not depend on it)
    compute: ComputeConfig = field(default_factory=ComputeConfig)  # where the stages train and score
    settings: Any = None  # the algorithm's own settings (`LifelongAlgorithm.Settings`), read back from the record
    kept: list[str] = field(default_factory=list)

    def fresh_start(self) -> dict[str, Any]:
        """How the first network starts: over the features of all K tasks, from the pretrained policy's
        weights where they fit (LIBERO-100) or freshly initialised."""
        pretrained = self.config.get("pretrained")
        return {"features": self.features, "pretrained": None if pretrained is None else pretrained["path"]}

    def stage_dir(self, k: int) -> str:
        return str(self.out / "stages" / f"task_{k}")

    def train(self, out: str, tune: FineTuning, epochs: int, label: str) -> None:
        """One `train_policy` run of the stage policy (resumable), reporting its epochs in the status line."""
        cfg = self.config
        train_policy(
            self.paths,
            out,
            stage_policy_config(cfg, epochs),
            fine_tuning=tune,
            successful_only=False,
            resume=True,
            progress=False,
            compute=self.compute,
            on_epoch_end=lambda info: self.status(f"{label}: epoch {info['epoch']}/{epochs}, nll {info['nll']:.3f}"),
        )

    def evaluate(self, policy: str, positions: Sequence[int], run_dir: Path) -> np.ndarray:
        """Success (row 0) and ESR (row 1) of `policy` on the tasks at `positions` of the learning order, from
        one base-mode evaluation without critic; a finished run directory is read back, not re-run."""
        cfg = self.config
        summary_path = run_dir / "summary.json"
        if summary_path.exists():
            summary = read_json_file(summary_path, "evaluation summary")
        else:
            summary = evaluate(
                cfg["suite"],
                [cfg["tasks"][p] for p in positions],
                policy,
                None,
                out=run_dir,
                resume=True,
                progress=False,
                workers=self.workers,
                compute=self.compute,
                mode="base",
                episodes=cfg["episodes"],
                seed=cfg["seed"],
                max_steps=cfg["max_steps"],
            )
        blocks = [summary["per_task"][cfg["task_keys"][p]] for p in positions]
        return np.array([[b["success_rate"] for b in blocks], [b["esr"] for b in blocks]])


def publish_policy(policy_dir: str, net: Any, features: BCFeatures, artifact: dict[str, Any], **facts: Any) -> None:
    """Write `net` as a policy directory, recording `facts` beside the training facts it was derived from."""
    os.makedirs(policy_dir, exist_ok=True)
    write_artifact(policy_dir, net, features, artifact["model"], {**artifact["training"], **facts})


def policy_done(policy_dir: str | Path) -> bool:
    """A policy directory is complete once its config.json, published last, exists."""
    return os.path.exists(os.path.join(policy_dir, "config.json"))
