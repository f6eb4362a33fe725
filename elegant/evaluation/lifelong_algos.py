"""LIBERO's lifelong algorithms as stages of `elegant lifelong` (`libero/lifelong/algos`; docs/design.md §8.3).

Every algorithm learns task k from the network kept after task k-1 (task 0 from a fresh network over the
features of all K tasks) and differs in three places, which are this module's `Algorithm` methods:

- `mechanisms(run, k)`: what the training step of stage k adds (`elegant.policies.continual`): nothing
  (SeqL), a replay memory of tasks 0..k-1 (ER), a penalty towards the weights kept after k-1 with their
  Fisher information (EWC), or the weights stage k may change (PackNet).
- `end_task(run, k, kept)`: after the best checkpoint of stage k is kept: EWC adds task k's Fisher
  information to the anchor; PackNet prunes the kept network and fine-tunes what is left, keeping the
  best fine-tuning checkpoint by success (not counted in the learning curve, as in LIBERO).
- `earlier(run, k)`: the policy each earlier task is evaluated with after task k: the kept network for
  all of them, or for PackNet one network per task j holding the weights of tasks 0..j only.

Multitask training (the upper bound) has no stages; `elegant.evaluation.lifelong` runs it apart.
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
from elegant.policies.bc_artifact import read_artifact, write_artifact
from elegant.policies.bc_config import BCConfig
from elegant.policies.bc_data import DemoSet
from elegant.policies.bc_features import BCFeatures
from elegant.policies.bc_train import FineTuning, demo_batches, select_tasks, snapshot_dir, train_policy
from elegant.policies.continual import (
    ElasticAnchor,
    WeightMasks,
    consolidate,
    fisher_information,
    replay_memory,
)

EWC_ANCHOR_FILE = "ewc_anchor.pt"
PACKNET_MASKS_FILE = "packnet_masks.pt"


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


def _publish(policy_dir: str, net: Any, features: BCFeatures, artifact: dict[str, Any], **facts: Any) -> None:
    """Write `net` as a policy directory, recording `facts` beside the training facts it was derived from."""
    os.makedirs(policy_dir, exist_ok=True)
    write_artifact(policy_dir, net, features, artifact["model"], {**artifact["training"], **facts})


def _done(policy_dir: str | Path) -> bool:
    """A policy directory is complete once its config.json, published last, exists."""
    return os.path.exists(os.path.join(policy_dir, "config.json"))


class Sequential:
    """SeqL: plain fine-tuning of the kept network on each new task."""

    def mechanisms(self, run: LifelongRun, k: int) -> dict[str, Any]:
        return {}

    def train_stage(self, run: LifelongRun, k: int) -> None:
        """Stage k: task k's demos, starting where task k-1 left the network, snapshots at the evaluation epochs."""
        cfg = run.config
        start = run.fresh_start() if k == 0 else {"init_from": run.kept[k - 1]}
        tune = FineTuning(
            tasks=[cfg["task_keys"][k]], snapshot_epochs=cfg["eval_epochs"], **start, **self.mechanisms(run, k)
        )
        run.train(run.stage_dir(k), tune, cfg["epochs"], cfg["task_keys"][k])

    def end_task(self, run: LifelongRun, k: int, kept: str) -> tuple[str, np.ndarray | None]:
        """The network task k leaves behind and its (success, ESR) on task k, None: that of `kept`."""
        return kept, None

    def earlier(self, run: LifelongRun, k: int) -> list[tuple[str, list[int], Path]]:
        """(policy, positions of earlier tasks, evaluation run directory) for S[k, :k]."""
        return [(run.kept[k], list(range(k)), run.out / "evals" / f"after_task_{k}")]


class ExperienceReplay(Sequential):
    """ER: every batch of task k is joined by as many samples of the memory of tasks 0..k-1."""

    def mechanisms(self, run: LifelongRun, k: int) -> dict[str, Any]:
        if k == 0:
            return {}
        memory = run.config["algorithm_settings"]["er_memory"]
        return {"replay": replay_memory(run.data, run.config["task_keys"][:k], memory)}


class ElasticWeightConsolidation(Sequential):
    """EWC: stage k is penalised towards the network kept after task k-1, weighted by the Fisher information
    of tasks 0..k-1 (older tasks decayed by gamma per task)."""

    def anchor_path(self, run: LifelongRun, k: int) -> str:
        return os.path.join(run.stage_dir(k), EWC_ANCHOR_FILE)

    def mechanisms(self, run: LifelongRun, k: int) -> dict[str, Any]:
        if k == 0:
            return {}
        return {
            "anchor": ElasticAnchor.load(self.anchor_path(run, k - 1), run.config["algorithm_settings"]["ewc_lambda"])
        }

    def end_task(self, run: LifelongRun, k: int, kept: str) -> tuple[str, np.ndarray | None]:
        path = self.anchor_path(run, k)
        if not os.path.exists(path):
            run.status(f"{run.config['task_keys'][k]}: Fisher information")
            cfg, settings = run.config, run.config["algorithm_settings"]
            net, features, artifact = read_artifact(kept)
            defaults = stage_policy_config(cfg)
            batches = demo_batches(
                select_tasks(run.data, [cfg["task_keys"][k]]),
                features,
                chunk=defaults.chunk,
                batch_size=defaults.batch_size,
                seed=cfg["seed"] + k,
            )
            previous = None if k == 0 else self.mechanisms(run, k)["anchor"]
            fisher = fisher_information(net, batches, "cpu")
            consolidate(previous, fisher, net, settings["ewc_lambda"], settings["ewc_gamma"]).save(path)
        return kept, None


class PackNet(Sequential):
    """PackNet: task k trains the free weights only; then the smallest of them are pruned and the rest
    fine-tuned; task j is evaluated with the weights of tasks 0..j."""

    def masks_path(self, run: LifelongRun, k: int) -> str:
        return os.path.join(run.stage_dir(k), "pruned", PACKNET_MASKS_FILE)

    def mechanisms(self, run: LifelongRun, k: int) -> dict[str, Any]:
        if k == 0:
            return {"masks": WeightMasks({}, 0, claim_free=True)}
        return {"masks": WeightMasks.load(self.masks_path(run, k - 1), k, claim_free=True)}

    def end_task(self, run: LifelongRun, k: int, kept: str) -> tuple[str, np.ndarray | None]:
        cfg, settings = run.config, run.config["algorithm_settings"]
        pruned = os.path.join(run.stage_dir(k), "pruned")
        if not _done(pruned):
            net, features, artifact = read_artifact(kept)
            masks = self.mechanisms(run, k)["masks"].bind(net, kept).prune(net, settings["packnet_prune"])
            os.makedirs(pruned, exist_ok=True)
            masks.save(self.masks_path(run, k))  # before the policy, whose config.json marks the step done
            _publish(pruned, net, features, artifact, packnet_pruned_from=os.path.abspath(kept))
        post = os.path.join(run.stage_dir(k), "post")
        post_epochs = list(range(0, settings["packnet_epochs"] + 1, cfg["eval_every"]))
        if not _done(post):
            run.status(f"{cfg['task_keys'][k]}: fine-tuning after pruning")
            masks = WeightMasks.load(self.masks_path(run, k), k)
            tune = FineTuning(tasks=[cfg["task_keys"][k]], init_from=pruned, snapshot_epochs=post_epochs, masks=masks)
            run.train(post, tune, settings["packnet_epochs"], f"{cfg['task_keys'][k]} after pruning")
        rates = [
            run.evaluate(snapshot_dir(post, e), [k], run.out / "evals" / f"task_{k}" / f"post_epoch_{e}")[:, 0]
            for e in post_epochs
        ]
        best = int(np.argmax([r[0] for r in rates]))  # the first best, as LIBERO's strict improvement
        return snapshot_dir(post, post_epochs[best]), rates[best]

    def earlier(self, run: LifelongRun, k: int) -> list[tuple[str, list[int], Path]]:
        masks = WeightMasks.load(self.masks_path(run, k), k)
        plans = []
        for j in range(k):
            policy = os.path.join(run.stage_dir(k), f"for_task_{j}")
            if not _done(policy):
                net, features, artifact = read_artifact(run.kept[k])
                masks.only_tasks_up_to(net, j)
                _publish(policy, net, features, artifact, packnet_weights_of_tasks=list(range(j + 1)))
            plans.append((policy, [j], run.out / "evals" / f"after_task_{k}" / f"task_{j}"))
        return plans


# The algorithms learned in stages; "multitask" trains on all tasks at once (`elegant.evaluation.lifelong`).
STAGED_ALGORITHMS: dict[str, Sequential] = {
    "seql": Sequential(),
    "er": ExperienceReplay(),
    "ewc": ElasticWeightConsolidation(),
    "packnet": PackNet(),
}
