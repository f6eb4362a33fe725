"""Behaviour cloning of the BC-GMM base policy from demonstration files.

Training is resumable to the same result: after every epoch a checkpoint (`out/checkpoint.pt`, written
atomically) holds the network, Adam and cosine-schedule state, the shuffling generator and the loss
history. The network is initialised under its own seed inside a forked RNG, and shuffling draws only
from that generator, so a resumed run replays exactly what the uninterrupted run would have done. A
checkpoint is only resumed with the same data and hyper-parameters; anything else is refused.

Sequential fine-tuning (the lifelong protocol, `elegant.evaluation.lifelong`) needs three more things: training on
some tasks of multi-task files (`tasks`), an input encoder fixed over more tasks than a stage trains on
(`features`) or inherited from the previous network (`init_from`, which also brings its weights), and
the network as of intermediate epochs (`snapshot_epochs`, published like the final policy, because the
protocol evaluates them and keeps the best). LIBERO's other lifelong baselines add one mechanism each to
the training step (`elegant.policies.continual`): a replay memory joined to every batch (ER), a penalty
towards the earlier tasks' weights (EWC), or weights the task may not change (PackNet).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from collections.abc import Callable, Collection, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch

from annotations import TaskFeatureEncoder
from base_suites.runtime.compute import ComputeConfig, device_kind, refuse_other_device, use_compute
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import changed_fields
from base_suites.runtime.outputs import check_output
from base_suites.runtime.records import RecordFormat, fill_missing
from base_suites.runtime.settings import with_overrides
from base_suites.runtime.training import Progress, Trainer
from critics.divergence import refuse_divergence
from elegant.policies.bc_artifact import MODEL_FILE, read_artifact, write_artifact
from elegant.policies.bc_config import BCConfig
from elegant.policies.bc_data import DemoSet, load_demos
from elegant.policies.bc_features import BCFeatures
from elegant.policies.bc_model import BCNet
from elegant.policies.continual import ElasticAnchor, WeightMasks, memory_digest
from elegant.policies.protocol import ACTION_DIM

CHECKPOINT_FILE = "checkpoint.pt"
Init = tuple[BCNet, BCFeatures, dict[str, Any]]  # what read_artifact returns for `init_from`


class _Windows:
    """All encoded states in one tensor; a batch's history windows and action chunks are gathered by index.

    The target of step t is the chunk of actions t .. t + chunk - 1 of its demo, flattened; a chunk that
    runs past the demo's end repeats its last action (the robot holding still), as diffusion-policy and
    ACT style chunking pad, so every step of every demo stays a training sample.
    """

    def __init__(self, data: DemoSet, features: BCFeatures, chunk: int = 1) -> None:
        encoded, starts, ends = [], [], []
        offset = 0
        for episode in data.episodes:
            encoded.append(features.encode(episode.states, features.context_of(episode)))
            starts.append(np.full(len(episode.states), offset))
            ends.append(np.full(len(episode.states), offset + len(episode.states) - 1))
            offset += len(episode.states)
        self.encoded = torch.from_numpy(np.concatenate(encoded))
        # state slots each row's task fills (the rest is padding): where observation noise may go
        self.widths = torch.tensor([features.noise_width(e) for e in data.episodes]).repeat_interleave(
            torch.tensor([len(e.states) for e in data.episodes])
        )
        self.starts = torch.from_numpy(np.concatenate(starts))
        self.ends = torch.from_numpy(np.concatenate(ends))
        self.actions = torch.from_numpy(np.concatenate([e.actions for e in data.episodes]))
        self.back = torch.arange(features.history - 1, -1, -1)
        self.ahead = torch.arange(int(chunk))
        self.features = features

    def __len__(self) -> int:
        return len(self.actions)

    def batch(
        self, index: torch.Tensor, noise: float = 0.0, generator: torch.Generator | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        rows = torch.maximum(index[:, None] - self.back, self.starts[index][:, None])
        targets = torch.minimum(index[:, None] + self.ahead, self.ends[index][:, None])
        window = self.encoded[rows]  # advanced indexing: a copy, safe to jitter in place
        if noise > 0:
            dim = self.features.state_dim
            filled = torch.arange(dim) < self.widths[rows][..., None]
            window[..., :dim] += torch.randn(window[..., :dim].shape, generator=generator) * noise * filled
        return self.features.flatten_window(window), self.actions[targets].flatten(1)


def demo_batches(
    data: DemoSet, features: BCFeatures, *, chunk: int, batch_size: int, seed: int
) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """All of `data`'s samples as model inputs and targets, in batches of a seeded shuffle (EWC's Fisher
    estimate goes over a task's data this way, as LIBERO's does over a shuffled loader)."""
    windows = _Windows(data, features, chunk)
    order = torch.randperm(len(windows), generator=torch.Generator().manual_seed(int(seed)))
    return [windows.batch(index) for index in order.split(int(batch_size))]


def _checkpoint_from_v1(state: dict[str, Any]) -> dict[str, Any]:
    """A version-1 checkpoint (it named no format) as version 2: its fingerprint gains the settings added
    since, at what those runs did: every demo (before the success filter), no observation noise, the task
    one-hot, plain training (before the lifelong mechanisms), a fresh start (before pre-training) and the
    CPU (before the device was recorded)."""
    added = {"successful_only": False, "config": {"obs_noise": 0.0, "encoding": "task-onehot"}}
    added |= {"continual": None, "pretrained": None}
    return fill_missing(state, {"fingerprint": added, "device": "cpu"})  # and trained on the CPU


CHECKPOINT_RECORD = RecordFormat("libero-elegant-policy-checkpoint", 2, {1: _checkpoint_from_v1})


def _check_fingerprint(path: str, state: dict[str, Any], fingerprint: dict[str, Any]) -> None:
    """Refuse a checkpoint of other data, settings or starting point, naming the first field that differs."""
    changed = changed_fields(state.get("fingerprint"), fingerprint)
    if changed:
        key, was, now = changed[0]
        raise UserInputError(f"{path}: cannot resume, field {key!r} was {was!r} and is now {now!r}")


def snapshot_dir(out: str, epoch: int) -> str:
    """Where `train_policy(..., snapshot_epochs=...)` publishes the policy as of `epoch` (0: before training)."""
    return os.path.join(out, f"epoch_{int(epoch)}")


def select_tasks(data: DemoSet, tasks: Sequence[str] | None) -> DemoSet:
    """The demos of `tasks` only (None: all), refusing a task the files hold no demo of."""
    if tasks is None:
        return data
    wanted = list(dict.fromkeys(tasks))
    episodes = [e for e in data.episodes if e.task in wanted]
    missing = [t for t in wanted if t not in {e.task for e in episodes}]
    if missing:
        files = ", ".join(f["path"] for f in data.files)
        raise UserInputError(
            f"{files}: no demos of task {', '.join(missing)}; found only {', '.join(sorted(data.layouts))}"
        )
    return DemoSet({k: data.layouts[k] for k in wanted}, episodes, data.files)


def _input_features(
    data: DemoSet, cfg: BCConfig, features: BCFeatures | None, init: Init | None, init_from: str | None
) -> BCFeatures:
    """Fit the features on the data unless they are fixed by the caller or come with the init network."""
    if init is not None:
        if features is not None:
            raise UserInputError(
                "train_policy: give features or init_from, not both (init_from brings its policy's features)"
            )
        features = init[1]
    elif features is None:
        return BCFeatures.fit(data, history=cfg.history, min_std=cfg.obs_min_std, encoding=cfg.encoding)
    where = init_from or "train_policy: features"
    if features.history != cfg.history:
        raise UserInputError(
            f"{where}: input history is {features.history} states but this run has history={cfg.history}"
        )
    if features.encoder.kind != cfg.encoding:
        raise UserInputError(f"{where}: its input encoding is {features.encoder.kind} but this run has {cfg.encoding}")
    if isinstance(features.encoder, TaskFeatureEncoder):
        for key, layout in data.layouts.items():
            if features.encoder.layouts.get(key) != layout:
                raise UserInputError(
                    f"{where}: the input encoder does not know task {key} with the layout of the demo files"
                )
    for episode in data.episodes:  # a goal the goal-relative encoding cannot read is refused here
        features.context_of(episode)
    return features


def network_spec(features: BCFeatures, cfg: BCConfig) -> dict[str, Any]:
    """The network a run of `cfg` over the input `features` builds, as its artifact records it ("model")."""
    return {
        "input_dim": features.input_dim,
        "hidden": list(cfg.hidden),
        "action_dim": ACTION_DIM * cfg.chunk,
        "modes": cfg.modes,
        "min_std": cfg.min_std,
        "chunk": cfg.chunk,
        "task_dim": features.binary_dim if cfg.task_film else 0,
    }


def _start_from(net: BCNet, init: Init, model_spec: dict[str, Any], init_from: str) -> None:
    """Copy the init network's weights into `net`, refusing a network of another shape."""
    old = init[2]["model"]
    for key, value in model_spec.items():
        if old.get(key) != value:
            raise UserInputError(f"{init_from}: model.{key} is {old.get(key)!r} but this run needs {value!r}")
    net.load_state_dict(init[0].state_dict())


def _transfer(net: BCNet, pretrained: Init) -> list[str]:
    """Copy into `net` every parameter of the pretrained network with the same name and shape; returns
    their names. A task-onehot policy over other tasks differs in its input layer and task conditioning
    (other state layouts, another one-hot), which stay as initialised; the hidden layers and the head carry
    over. Goal-relative policies share every shape: all of it carries over."""
    source = pretrained[0].state_dict()
    target = net.state_dict()
    copied = [k for k, v in source.items() if k in target and target[k].shape == v.shape]
    net.load_state_dict({**target, **{k: source[k] for k in copied}})
    return copied


def _digest(obj: Any) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()


@dataclass(frozen=True)
class FineTuning:
    """What a training run starts from and publishes beyond the plain case (LIBERO's lifelong stages).

    `tasks` (task keys) trains on those tasks' demos only; `features` fixes the model input instead of
    fitting it on the data (e.g. fitted over more tasks than this run trains on); `init_from` starts from
    a policy directory's weights and features instead of a fresh network (not with `features`);
    `snapshot_epochs` also publishes the policy as of these epochs (0: before training) in
    `snapshot_dir(out, epoch)`. `pretrained` (a policy directory, e.g. trained on another suite) starts
    the fresh network from its weights wherever names and shapes agree (LIBERO-100: pre-train on
    libero_90, then learn libero_10). `replay` (ER): demos of earlier tasks, of which every batch is joined by
    as many samples, drawn uniformly; `anchor` (EWC): its penalty is added to the loss; `masks` (PackNet):
    only the weights `masks.task` owns train. `tasks`, the fixed features, the init policy and these three
    are part of what a resumed checkpoint must match."""

    tasks: Sequence[str] | None = None
    features: BCFeatures | None = None
    init_from: str | None = None
    snapshot_epochs: Collection[int] = ()
    pretrained: str | None = None
    replay: DemoSet | None = None
    anchor: ElasticAnchor | None = None
    masks: WeightMasks | None = None

    def continual(self) -> dict[str, str | None] | None:
        """The lifelong mechanisms by content (None: plain training), for the checkpoint's fingerprint."""
        if self.replay is None and self.anchor is None and self.masks is None:
            return None
        return {
            "replay": None if self.replay is None else memory_digest(self.replay),
            "anchor": None if self.anchor is None else self.anchor.digest(),
            "masks": None if self.masks is None else self.masks.digest(),
        }


def train_policy(
    paths: Sequence[str],
    out: str,
    config: BCConfig | None = None,
    *,
    successful_only: bool = True,
    fine_tuning: FineTuning | None = None,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = True,
    on_epoch_end: Callable[[dict[str, Any]], None] | None = None,
    compute: ComputeConfig | None = None,
    **settings: Any,
) -> dict[str, Any]:
    """Train a BC-GMM policy on the demos in `paths` and write it to the directory `out`.

    The hyper-parameters are `config`'s (default: `BCConfig`'s defaults), with keyword `settings` naming
    `BCConfig` fields overriding it. `chunk` > 1 trains the policy to predict that many future actions at
    once (one GMM over the flattened chunk) and to execute them open-loop, as the action chunks of VLA
    policies: a sample of the mixture is then a coherent sub-trajectory, which is what JITI chooses among
    (see `BCPolicy`). `successful_only`: train on the successful demos only (see `load_demos`); the data a
    checkpoint records then counts only those. `fine_tuning`: see `FineTuning`. A directory that holds a
    checkpoint or a policy is continued with `resume` or started afresh with `overwrite`, else refused.

    Returns a dict: out, epochs, resumed_from_epoch, loss_history (mean training NLL per epoch), final_nll,
    num_demos, num_samples, tasks, seconds. `on_epoch_end` receives {"epoch", "nll"} after each epoch's
    checkpoint is on disk (for logging; an exception raised there stops training like a crash would).
    compute: the device and CPU threads (`ComputeConfig`; default: a GPU when torch sees one). Batches and
    their observation noise are drawn on the CPU on every device; a checkpoint resumes on the kind of device
    it was written on only.
    """
    cfg = with_overrides(config or BCConfig(), settings, "train_policy")
    tune = fine_tuning or FineTuning()
    tasks, features, init_from, snapshot_epochs = tune.tasks, tune.features, tune.init_from, tune.snapshot_epochs
    cfg.validate()
    device = use_compute(compute or ComputeConfig(), "train-policy")
    snapshots = set(snapshot_epochs)
    if any(int(e) != e or not 0 <= e <= cfg.epochs for e in snapshots):
        raise UserInputError(
            f"train_policy: snapshot_epochs must be epochs in 0..{cfg.epochs}, got {sorted(snapshots)}"
        )
    check_output(out, "dir", resume=resume, overwrite=overwrite, results=(CHECKPOINT_FILE, MODEL_FILE))
    started = time.perf_counter()
    data = select_tasks(load_demos(paths, successful_only), tasks)
    init = read_artifact(init_from) if init_from is not None else None
    if tune.pretrained is not None and init is not None:
        raise UserInputError("train_policy: give init_from or pretrained, not both (init_from brings every weight)")
    pretrained = read_artifact(tune.pretrained) if tune.pretrained is not None else None
    origin = {  # what this run starts from beyond the files and the config: recorded, and checked on resume
        "tasks": None if tasks is None else list(data.layouts),
        "features": None if features is None else _digest(features.to_dict()),
        # The start network by content, not by path: a moved or copied run directory still resumes.
        "init_from": None if init is None else {"model_sha256": init[2]["model_sha256"]},
        "pretrained": None if pretrained is None else {"model_sha256": pretrained[2]["model_sha256"]},
        "successful_only": bool(successful_only),
        "continual": tune.continual(),
    }
    features = _input_features(data, cfg, features, init, init_from)
    windows = _Windows(data, features, cfg.chunk)
    replay = None if tune.replay is None else _Windows(tune.replay, features, cfg.chunk)
    model_spec = network_spec(features, cfg)

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(cfg.seed)
        net = BCNet(
            features.input_dim,
            hidden=cfg.hidden,
            action_dim=ACTION_DIM * cfg.chunk,
            modes=cfg.modes,
            min_std=cfg.min_std,
            task_dim=model_spec["task_dim"],
        )
    if init is not None:
        _start_from(net, init, model_spec, init_from)
    if pretrained is not None and not _transfer(net, pretrained):
        raise UserInputError(f"{tune.pretrained}: no layer of this policy fits the network trained here")
    masks = None if tune.masks is None else tune.masks.bind(net, init_from or out)
    net.to(device)
    steps_per_epoch = math.ceil(len(windows) / cfg.batch_size)

    optimizer = torch.optim.Adam(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    training = _PolicyTraining(
        cfg=cfg,
        out=out,
        net=net,
        device=device,
        windows=windows,
        replay=replay,
        optimizer=optimizer,
        scheduler=torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=cfg.epochs * steps_per_epoch),
        generator=torch.Generator().manual_seed(cfg.seed),
        masks=masks,
        anchor=None if tune.anchor is None else tune.anchor.to(device),
        snapshots=snapshots,
        on_epoch_end=on_epoch_end,
        fingerprint={"config": asdict(cfg), "data": data.files, **origin},
        artifact=lambda losses: {
            "config": asdict(cfg),
            "data": data.files,
            "loss_history": list(losses),
            "num_samples": len(windows),
            **origin,
            "init_from_path": None if init_from is None else os.path.abspath(init_from),
            "device": device_kind(device),
        },
        publish_model=lambda directory, training: write_artifact(directory, net, features, model_spec, training),
        summary={"num_demos": len(data.episodes), "tasks": list(features.encoder.tasks), "started": started},
    )
    trainer = Trainer(
        "train-policy", out, CHECKPOINT_FILE, (CHECKPOINT_FILE, MODEL_FILE), cfg.epochs, steps_per_epoch, "batch"
    )
    return trainer.run(training, resume=resume, overwrite=overwrite, progress=progress)


@dataclass
class _PolicyTraining:
    """train-policy's `Training`: its units are epochs, each a seeded shuffle of every sample in batches
    (joined by as many replayed samples with ER, penalised with EWC, with PackNet's frozen weights kept);
    a snapshot epoch is published before its checkpoint, so a crash in between redoes the epoch and
    rewrites the snapshot."""

    cfg: BCConfig
    out: str
    net: BCNet
    device: torch.device
    windows: _Windows
    replay: _Windows | None
    optimizer: torch.optim.Optimizer
    scheduler: Any
    generator: torch.Generator
    masks: WeightMasks | None
    anchor: ElasticAnchor | None
    snapshots: set[int]
    on_epoch_end: Callable[[dict[str, Any]], None] | None
    fingerprint: dict[str, Any]
    artifact: Callable[[list[float]], dict[str, Any]]  # the training record a published policy holds
    publish_model: Callable[[str, dict[str, Any]], None]
    summary: dict[str, Any]
    losses: list[float] = field(default_factory=list)

    def publish(self, directory: str) -> None:
        """Write the network as it is now as a policy directory (the final one, or a snapshot)."""
        os.makedirs(directory, exist_ok=True)
        self.publish_model(directory, self.artifact(self.losses))

    def resume(self, state: dict[str, Any], path: str) -> int:
        state = CHECKPOINT_RECORD.upgrade(state, path)
        _check_fingerprint(path, state, self.fingerprint)
        refuse_other_device(path, state["device"], self.device)
        self.net.load_state_dict(state["model"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.scheduler.load_state_dict(state["scheduler"])
        self.generator.set_state(state["generator"])
        self.losses = list(state["losses"])
        return int(state["epoch"])

    def begin(self, start: int) -> None:
        if start == 0 and 0 in self.snapshots:
            self.publish(snapshot_dir(self.out, 0))
        self.restore_frozen = None if self.masks is None else self.masks.freeze(self.net)
        self.net.train()

    def unit(self, n: int, bar: Progress) -> None:
        cfg, windows, replay, generator = self.cfg, self.windows, self.replay, self.generator
        total = 0.0
        for index in torch.randperm(len(windows), generator=generator).split(cfg.batch_size):
            x, actions = windows.batch(index, cfg.obs_noise, generator)
            if replay is not None:
                drawn = torch.randint(len(replay), (len(index),), generator=generator)
                x, actions = (
                    torch.cat(pair) for pair in zip((x, actions), replay.batch(drawn, cfg.obs_noise, generator))
                )
            loss = self.net.nll(x.to(self.device), actions.to(self.device)).mean()
            objective = loss if self.anchor is None else loss + self.anchor.penalty(self.net)
            self.optimizer.zero_grad(set_to_none=True)
            objective.backward()
            if cfg.grad_clip > 0:
                torch.nn.utils.clip_grad_norm_(self.net.parameters(), cfg.grad_clip)
            self.optimizer.step()
            if self.restore_frozen is not None:
                self.restore_frozen()
            self.scheduler.step()
            total += loss.item() * len(index)
            bar.update(1)
        self.losses.append(total / len(windows))
        bar.set_postfix(epoch=n, nll=f"{self.losses[-1]:.3f}")
        refuse_divergence("train-policy", f"epoch {n}", {"nll": self.losses[-1]}, self.net)
        if n in self.snapshots:
            self.publish(snapshot_dir(self.out, n))

    def checkpoint(self, n: int) -> dict[str, Any]:
        return {
            "format": CHECKPOINT_RECORD.tag,
            "epoch": n,
            "model": self.net.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict(),
            "generator": self.generator.get_state(),
            "losses": self.losses,
            "fingerprint": self.fingerprint,
            "device": device_kind(self.device),
        }

    def checkpointed(self, n: int) -> None:
        if self.on_epoch_end is not None:
            self.on_epoch_end({"epoch": n, "nll": self.losses[-1]})

    def finish(self, start: int) -> dict[str, Any]:
        self.net.eval()
        result = {
            "out": self.out,
            "epochs": self.cfg.epochs,
            "resumed_from_epoch": start,
            "loss_history": self.losses,
            "final_nll": self.losses[-1],
            "num_demos": self.summary["num_demos"],
            "num_samples": len(self.windows),
            "tasks": self.summary["tasks"],
            "seconds": time.perf_counter() - self.summary["started"],
            "device": device_kind(self.device),
        }
        self.publish(self.out)
        return result
