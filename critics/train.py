"""Offline Cal-QL training of the elegance critic: data, loop, checkpoints, resume, metrics, artifact.

Output directory:
    checkpoint.pt   everything a resumed run needs (written atomically every `checkpoint_every` steps
                    and at the end): loss module state (actor, critics, target critics, temperatures),
                    optimiser state, the torch RNG state (uniform and policy action draws) and the replay
                    sampler's generator state, the step, the config and a fingerprint of the data;
    metrics.csv     one row every `log_every` steps (appended as training goes; on resume, rows after
                    the checkpoint's step are dropped, so the file matches an uninterrupted run);
    critic.pt, critic.json   the final critic (see `critics.artifact`).

A run killed at any point and resumed with `resume=True` continues from its last checkpoint to the same
parameters as an uninterrupted run with the same arguments (same seed, same thread count).
"""

from __future__ import annotations

import csv
import io
import os
import time
from collections.abc import Sequence
from dataclasses import asdict
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.objectives import SoftUpdate

from base_suites.runtime.compute import ComputeConfig, device_kind, refuse_other_device, use_compute
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import atomic_write, changed_fields, library_versions
from base_suites.runtime.outputs import check_output
from base_suites.runtime.records import RecordFormat, fill_missing
from base_suites.runtime.settings import with_overrides
from base_suites.runtime.training import Progress, Trainer
from base_suites.stack import cpu_record
from critics.artifact import WEIGHTS_FILE, save_critic
from critics.config import TrainConfig
from critics.data import TransitionData, load_transitions, make_replay_buffer
from critics.divergence import refuse_divergence
from critics.loss import CalQLLoss
from critics.networks import TanhGaussianActor, TwinQNetwork

_CPU = torch.device("cpu")


def _checkpoint_from_v1(state: dict[str, Any]) -> dict[str, Any]:
    """A version-1 checkpoint as version 2: its config gains the settings added since, each at the value
    those runs trained with (per-step actions, Cal-QL's backup, no weight decay or Monte-Carlo term, the
    squared error, no explored share, no bootstrap, the task one-hot over every task of the files)."""
    added = {"chunk": 1, "backup": "policy", "weight_decay": 0.0, "mc_weight": 0.0, "value_loss": "mse"}
    added |= {"explored_fraction": 0.0, "bootstrap": None, "encoding": "task-onehot", "tasks": None}
    return fill_missing(state, {"config": added, "device": "cpu"})  # and trained on the CPU


CHECKPOINT_RECORD = RecordFormat("libero-elegant/critic-checkpoint", 2, {1: _checkpoint_from_v1})
CHECKPOINT_FILE = "checkpoint.pt"
METRICS_FILE = "metrics.csv"
# Arguments that may change between a run and its resumption (they do not affect the numbers).
_RESUMABLE_CHANGES = ("steps", "checkpoint_every")


class _Run:
    """The modules, optimiser and random state of one training run."""

    def __init__(self, cfg: TrainConfig, data: TransitionData, device: torch.device = _CPU) -> None:
        torch.manual_seed(cfg.seed)
        # initialised on the CPU on every device, so a GPU run starts from the CPU run's weights
        critic = TwinQNetwork(data.obs_dim, data.action_dim, cfg.hidden)
        actor = TanhGaussianActor(data.obs_dim, data.action_dim, cfg.hidden)
        self.device, self.device_kind = device, device_kind(device)
        self.loss = CalQLLoss.from_config(actor, critic, cfg, data.gamma).to(device)
        self.updater = SoftUpdate(self.loss, tau=cfg.tau)
        groups = [
            {"params": list(self.loss.actor_network_params.values(True, True)), "lr": cfg.actor_lr},
            # Decay shrinks Q's dependence on state details the few starts make memorisable (a Q that
            # tells the episodes apart by their states need not rank the actions taken in one of them).
            {
                "params": list(self.loss.qvalue_network_params.values(True, True)),
                "lr": cfg.critic_lr,
                "weight_decay": cfg.weight_decay,
            },
            {"params": [self.loss.log_alpha], "lr": cfg.alpha_lr},
        ]
        if cfg.with_lagrange:
            groups.append({"params": [self.loss.log_alpha_prime], "lr": cfg.critic_lr})
        self.optimizer = torch.optim.Adam(groups, decoupled_weight_decay=True)  # with no decay, plain Adam
        self.generator = torch.Generator().manual_seed(cfg.seed)
        self.buffer = make_replay_buffer(data.transitions, cfg.batch_size - cfg.explored_per_batch, self.generator)
        # Explored decisions are the only transitions whose action was drawn independently of the state;
        # on the others the policy's action is a function of the state, and a critic can score the action
        # by what it says about the state rather than by what it does. Oversampling them lets the critic
        # learn what an action changes. They are rare (about one transition in 90 of a branch-rollout file).
        self.explored_buffer = None
        if cfg.explored_per_batch:
            rows = data.explored.nonzero().flatten()
            if not len(rows):
                raise UserInputError(
                    f"train-critic: explored_fraction {cfg.explored_fraction} but no demo in {', '.join(cfg.paths)} "
                    "has "
                    "explored_steps (record some with `elegant rollouts --explore` or `--explore-at`)"
                )
            self.explored_buffer = make_replay_buffer(data.transitions[rows], cfg.explored_per_batch, self.generator)

    def step(self) -> TensorDictBase:
        """One gradient step on a fresh batch; returns the loss module's output (losses and diagnostics)."""
        batch = self.buffer.sample()
        if self.explored_buffer is not None:
            batch = torch.cat([batch, self.explored_buffer.sample()])
        losses = self.loss(batch.to(self.device))
        total = sum(v for k, v in losses.items() if k.startswith("loss_"))
        self.optimizer.zero_grad(set_to_none=True)
        total.backward()
        self.optimizer.step()
        self.updater.step()
        return losses

    def state(self, step: int, cfg: TrainConfig, fingerprint: str) -> dict[str, Any]:
        return {
            "format": CHECKPOINT_RECORD.tag,
            "step": step,
            "config": asdict(cfg),
            "fingerprint": fingerprint,
            "loss": self.loss.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "torch_rng": torch.get_rng_state(),
            "sampler_rng": self.generator.get_state(),
            # the policy's action draws come from the GPU's generator on a GPU
            "cuda_rng": torch.cuda.get_rng_state(self.device) if self.device.type == "cuda" else None,
            "device": self.device_kind,
            "versions": library_versions(),
            "machine": cpu_record(),  # trained weights depend on the CPU's float kernels
        }

    def restore(self, state: dict[str, Any]) -> None:
        self.loss.load_state_dict(state["loss"])
        self.optimizer.load_state_dict(state["optimizer"])
        torch.set_rng_state(state["torch_rng"])
        self.generator.set_state(state["sampler_rng"])
        if self.device.type == "cuda":
            torch.cuda.set_rng_state(state["cuda_rng"], self.device)


def _check_resumable(
    path: str, state: dict[str, Any], cfg: TrainConfig, fingerprint: str, device: torch.device
) -> None:
    changed = changed_fields(state["config"], asdict(cfg), ignore=_RESUMABLE_CHANGES)
    if changed:
        raise UserInputError(
            f"{path}: cannot resume with different {', '.join(k for k, _, _ in changed)} (checkpoint has "
            + ", ".join(f"{k}={saved!r}" for k, saved, _ in changed)
            + ")"
        )
    if state["fingerprint"] != fingerprint:
        raise UserInputError(
            f"{path}: the training data changed since this checkpoint was written (fingerprint differs)"
        )
    refuse_other_device(path, state["device"], device)


class _MetricsLog:
    """metrics.csv: a header, then one row per logged step; appended and flushed as training goes."""

    def __init__(self, path: str, columns: list[str], keep_until: int | None) -> None:
        self.path, self.columns = path, ["step", *columns]
        rows = self._rows_until(keep_until) if keep_until is not None else []
        buffer = io.StringIO()
        writer = csv.writer(buffer)
        writer.writerow(self.columns)
        writer.writerows(rows)
        atomic_write(path, buffer.getvalue())

    def _rows_until(self, step: int) -> list[list[str]]:
        if not os.path.exists(self.path):
            return []
        with open(self.path, newline="") as f:
            rows = list(csv.reader(f))[1:]
        return [r for r in rows if len(r) == len(self.columns) and r[0].isdigit() and int(r[0]) <= step]

    def append(self, step: int, values: dict[str, float]) -> None:
        with open(self.path, "a", newline="") as f:
            csv.writer(f).writerow([step, *(f"{values[c]:.6g}" for c in self.columns[1:])])


def train_critic(
    paths: Sequence[str],
    out: str,
    config: TrainConfig | None = None,
    *,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = True,
    compute: ComputeConfig | None = None,
    **settings: Any,
) -> dict[str, Any]:
    """Train a Cal-QL elegance critic on annotated HDF5 files; write checkpoints, metrics and the critic to `out`.

    paths: annotated files (`elegant annotate`), all with the same gamma. The settings are `config`'s
    (default: `TrainConfig`'s defaults), with keyword `settings` naming `TrainConfig` fields overriding it;
    see each field's help. resume: continue from out/checkpoint.pt (else a run refuses a directory that
    holds one or a critic, unless `overwrite` starts it afresh); steps and checkpoint_every may change on
    resume, nothing else.

    Returns a summary: out (the directory, loadable with `critics.load`), steps, resumed_from (the
    checkpoint step a resumed run started from, else None), transitions, demos, tasks, gamma, seconds,
    steps_per_second (of this invocation), and final (the last logged value of every loss and diagnostic).
    """
    paths = [os.path.abspath(p) for p in paths]
    cfg = with_overrides(config or TrainConfig(), {**settings, "paths": paths}, "train-critic")
    cfg.validate()
    device = use_compute(compute or ComputeConfig(), "train-critic")
    check_output(out, "dir", resume=resume, overwrite=overwrite, results=(CHECKPOINT_FILE, WEIGHTS_FILE))
    data = load_transitions(cfg.paths, cfg)
    trainer = Trainer("train-critic", out, CHECKPOINT_FILE, (CHECKPOINT_FILE, WEIGHTS_FILE), cfg.steps)
    return trainer.run(_CriticTraining(cfg, data, device, out), resume=resume, overwrite=overwrite, progress=progress)


class _CriticTraining:
    """train-critic's `Training`: its units are gradient steps; metrics.csv grows as it goes."""

    def __init__(self, cfg: TrainConfig, data: TransitionData, device: torch.device, out: str) -> None:
        self.cfg, self.data, self.out = cfg, data, out
        self.fingerprint = data.fingerprint()
        self.run = _Run(cfg, data, device)
        self.resumed_from: int | None = None
        self.losses: TensorDictBase | None = None
        self.last: dict[str, float] = {}

    def resume(self, state: dict[str, Any], path: str) -> int:
        state = CHECKPOINT_RECORD.upgrade(state, path)
        _check_resumable(path, state, self.cfg, self.fingerprint, self.run.device)
        if int(state["step"]) > self.cfg.steps:
            raise UserInputError(
                f"{path}: checkpoint is at step {state['step']}, beyond steps={self.cfg.steps}; ask for at least "
                "that many"
            )
        self.run.restore(state)
        self.resumed_from = int(state["step"])
        return self.resumed_from

    def begin(self, start: int) -> None:
        self.metrics = _MetricsLog(os.path.join(self.out, METRICS_FILE), self.run.loss.out_keys, self.resumed_from)
        self.began = time.perf_counter()

    def unit(self, n: int, bar: Progress) -> None:
        self.losses = self.run.step()
        if n % self.cfg.log_every == 0 or n == self.cfg.steps:
            self.last = {k: float(v.detach()) for k, v in self.losses.items()}
            self.metrics.append(n, self.last)
            shown = ("loss_qvalue", "loss_cql", "loss_actor", "alpha")
            bar.set_postfix({k.removeprefix("loss_"): f"{self.last[k]:.3g}" for k in shown})
        bar.update(1)

    def checkpoint(self, n: int) -> dict[str, Any] | None:
        if n % self.cfg.checkpoint_every and n != self.cfg.steps:
            return None
        values = {k: float(v.detach()) for k, v in self.losses.items()}
        refuse_divergence("train-critic", f"step {n}", values, self.run.loss)
        return self.run.state(n, self.cfg, self.fingerprint)

    def checkpointed(self, n: int) -> None:
        pass

    def finish(self, start: int) -> dict[str, Any]:
        seconds = time.perf_counter() - self.began
        cfg, data = self.cfg, self.data
        save_critic(
            self.out,
            self.run.loss.get_stateful_net("qvalue_network"),
            data.encoder,
            data.normalization,
            gamma=data.gamma,
            chunk=data.chunk,
            training={
                **asdict(cfg),
                "fingerprint": self.fingerprint,
                "transitions": len(data.transitions),
                "device": self.run.device_kind,
            },
        )
        trained = max(cfg.steps - start, 0)
        return {
            "out": self.out,
            "steps": cfg.steps,
            "resumed_from": self.resumed_from,
            "transitions": len(data.transitions),
            "demos": data.n_demos,
            "tasks": data.encoder.tasks,
            "gamma": data.gamma,
            "seconds": seconds,
            "steps_per_second": trained / seconds if trained and seconds > 0 else None,
            "device": self.run.device_kind,
            "final": self.last,
        }
