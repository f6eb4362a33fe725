"""What LIBERO's lifelong baselines change in a BC training run (Liu et al. 2023, `libero/lifelong/algos`).

Each is a mechanism `train_policy` applies when `FineTuning` carries it; the lifelong protocol
(`elegant.evaluation.lifelong_algos`, one class per algorithm) decides when each stage gets which:

- ER (experience replay): `replay_memory` keeps the first `samples` steps of each earlier task's demos
  (LIBERO's fixed-size memory per task, `n_memories`); every batch of the task being learned is joined by
  as many samples drawn from that memory, and the loss is the mean over both.
- EWC (elastic weight consolidation): `ElasticAnchor` holds the weights kept after earlier tasks and a
  diagonal Fisher information (squared gradients of the mean log-likelihood, batch by batch, averaged over
  the task's data and summed over tasks with an older-task decay `gamma`); the loss gains
  lambda * sum F (theta - theta*)^2.
- PackNet: `WeightMasks` gives every weight of every Linear layer an owner (0: free, t + 1: task t).
  A task trains only the weights it owns, the free ones at its start; biases never train (as LIBERO's
  PackNet fixes them); after the task a fraction of its weights, the smallest in magnitude, is pruned
  back to free (zeroed), and the network is fine-tuned on what remains. Task j is evaluated with the
  weights of tasks 0..j only, so a later task cannot change what task j computes.
"""

from __future__ import annotations

import hashlib
import io
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch
from torch import nn

from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import atomic_write
from elegant.policies.bc_data import DemoSet, Episode

OWNER_DTYPE = torch.int16  # up to 32766 tasks; LIBERO-90 needs 91 owners


def tensor_digest(tensors: dict[str, torch.Tensor]) -> str:
    """SHA-256 over names, shapes and bytes: what a resumed run checks its mechanism's inputs by."""
    digest = hashlib.sha256()
    for name in sorted(tensors):
        value = tensors[name].detach().cpu().contiguous()
        digest.update(f"{name}:{tuple(value.shape)}:{value.dtype}".encode())
        digest.update(value.numpy().tobytes())
    return digest.hexdigest()


def _save(path: str, tensors: dict[str, dict[str, torch.Tensor]]) -> None:
    buffer = io.BytesIO()
    torch.save(tensors, buffer)
    atomic_write(path, buffer.getvalue())


def _load(path: str, keys: Sequence[str], what: str) -> dict[str, dict[str, torch.Tensor]]:
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # a truncated or foreign file surfaces as many exception types
        raise UserInputError(f"{path}: unreadable {what} ({exc.__class__.__name__}); rerun its stage") from None
    if not isinstance(state, dict) or any(not isinstance(state.get(k), dict) for k in keys):
        raise UserInputError(f"{path}: not a {what} file (expected {', '.join(keys)})")
    return state


# ---- ER ----------------------------------------------------------------------------------------------------


def replay_memory(data: DemoSet, tasks: Sequence[str], samples: int) -> DemoSet:
    """The first `samples` steps of each of `tasks`' demos in file order, the last demo cut where the budget
    ends: LIBERO's per-task memory (the first `n_memories` samples of each earlier task's dataset)."""
    if int(samples) != samples or samples < 1:
        raise UserInputError(f"lifelong: er_memory must be a positive integer, got {samples!r}")
    episodes: list[Episode] = []
    for task in tasks:
        left = int(samples)
        for episode in (e for e in data.episodes if e.task == task):
            if left == 0:
                break
            take = min(left, len(episode.actions))
            episodes.append(replace(episode, states=episode.states[:take], actions=episode.actions[:take]))
            left -= take
    if not episodes:
        raise UserInputError("lifelong: the replay memory is empty (no earlier task has demos)")
    layouts = {t: data.layouts[t] for t in dict.fromkeys(e.task for e in episodes)}
    return DemoSet(layouts, episodes, data.files)


def memory_digest(memory: DemoSet) -> str:
    """Identifies a replay memory by content (tasks, states, actions) for resume checks."""
    digest = hashlib.sha256()
    for episode in memory.episodes:
        digest.update(episode.task.encode())
        digest.update(np.ascontiguousarray(episode.states).tobytes())
        digest.update(np.ascontiguousarray(episode.actions).tobytes())
    return digest.hexdigest()


# ---- EWC ---------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ElasticAnchor:
    """EWC's anchor: weights theta* kept after the earlier tasks, their Fisher information F, and lambda."""

    fisher: dict[str, torch.Tensor]
    anchor: dict[str, torch.Tensor]
    weight: float

    def penalty(self, net: nn.Module) -> torch.Tensor:
        """lambda * sum over parameters of F * (theta - theta*)^2: 0 at the anchor, growing with distance.
        F and theta* must be on `net`'s device (`to`)."""
        return self.weight * sum(
            (self.fisher[name] * (param - self.anchor[name]).square()).sum() for name, param in net.named_parameters()
        )

    def to(self, device: torch.device | str) -> ElasticAnchor:
        """This anchor with F and theta* on `device` (once per training run, not per step)."""
        return ElasticAnchor(
            {k: v.to(device) for k, v in self.fisher.items()},
            {k: v.to(device) for k, v in self.anchor.items()},
            self.weight,
        )

    def digest(self) -> str:
        return tensor_digest({**{f"F.{k}": v for k, v in self.fisher.items()}, **self.anchor}) + f":{self.weight!r}"

    def save(self, path: str) -> None:
        _save(path, {"fisher": self.fisher, "anchor": self.anchor})

    @classmethod
    def load(cls, path: str, weight: float) -> ElasticAnchor:
        state = _load(path, ("fisher", "anchor"), "EWC anchor")
        return cls(state["fisher"], state["anchor"], float(weight))


def fisher_information(
    net: nn.Module, batches: Sequence[tuple[torch.Tensor, torch.Tensor]], device: torch.device
) -> dict[str, torch.Tensor]:
    """Diagonal Fisher as LIBERO's EWC estimates it: per batch, the squared gradient of the batch's mean
    log-likelihood, averaged over the batches (CPU tensors, keyed like `net.named_parameters()`)."""
    fisher = {name: torch.zeros_like(p, device="cpu") for name, p in net.named_parameters()}
    net.train()
    for x, actions in batches:
        net.zero_grad(set_to_none=True)
        (-net.nll(x.to(device), actions.to(device))).mean().backward()
        for name, param in net.named_parameters():
            if param.grad is not None:
                fisher[name] += param.grad.detach().cpu().square()
    net.zero_grad(set_to_none=True)
    net.eval()
    return {name: value / len(batches) for name, value in fisher.items()}


def consolidate(
    previous: ElasticAnchor | None, fisher: dict[str, torch.Tensor], net: nn.Module, weight: float, gamma: float
) -> ElasticAnchor:
    """The anchor after one more task: F = gamma * F_before + F_task (F_task alone for the first task) and
    theta* = the network now."""
    if previous is not None:
        fisher = {name: gamma * previous.fisher[name] + value for name, value in fisher.items()}
    anchor = {name: p.detach().cpu().clone() for name, p in net.named_parameters()}
    return ElasticAnchor(fisher, anchor, float(weight))


# ---- PackNet -----------------------------------------------------------------------------------------------


def linear_weights(net: nn.Module) -> dict[str, nn.Parameter]:
    """The weight of every Linear layer of `net` by parameter name: what PackNet's masks cover."""
    return {f"{name}.weight": m.weight for name, m in net.named_modules() if isinstance(m, nn.Linear)}


@dataclass(frozen=True)
class WeightMasks:
    """PackNet's ownership of every Linear weight (0: free or pruned, t + 1: task t), and the task training.

    `claim_free`: the task starts here and takes every free weight (LIBERO's `start_task`); without it, as
    in the fine-tuning after pruning, pruned weights stay free and zero. `owner` may be empty before the
    first task; `bind` fills it in for a network. While `task` trains, `freeze` keeps every weight it does
    not own and every bias at its starting value."""

    owner: dict[str, torch.Tensor]
    task: int
    claim_free: bool = False

    def bind(self, net: nn.Module, where: str) -> WeightMasks:
        """These masks for `net` (refusing a network whose Linear layers they do not fit), free weights
        handed to `task` when it claims them."""
        weights = linear_weights(net)
        owner = self.owner or {k: torch.zeros(w.shape, dtype=OWNER_DTYPE) for k, w in weights.items()}
        if set(weights) != set(owner) or any(weights[k].shape != v.shape for k, v in owner.items()):
            raise UserInputError(f"{where}: the PackNet masks do not fit this network's layers")
        if self.claim_free:
            mine = torch.tensor(self.task + 1, dtype=OWNER_DTYPE)
            owner = {k: torch.where(v == 0, mine, v) for k, v in owner.items()}
        return WeightMasks(owner, self.task)

    def trainable(self, name: str) -> torch.Tensor:
        return self.owner[name] == self.task + 1

    def freeze(self, net: nn.Module) -> Callable[[], None]:
        """Call after `net` is on its device and in its starting state; returns what to call after every
        optimiser step: it puts back every value `task` may not change (the weights it does not own and
        every bias), so neither gradients nor weight decay move them. Adam updates each element on its
        own, so the weights `task` owns train as if the others had no gradient."""
        params = dict(net.named_parameters())
        frozen = {name: p.detach().clone() for name, p in params.items()}
        keep = {name: self.trainable(name).to(frozen[name].device) for name in linear_weights(net)}

        def restore() -> None:
            with torch.no_grad():
                for name, param in params.items():
                    param.copy_(torch.where(keep[name], param, frozen[name]) if name in keep else frozen[name])

        return restore

    def prune(self, net: nn.Module, fraction: float) -> WeightMasks:
        """Free the `fraction` of `task`'s weights smallest in magnitude, per layer, and zero them in `net`
        (LIBERO's `prune`: a weight at the cut-off value is pruned too)."""
        if not 0.0 <= fraction < 1.0:
            raise UserInputError(f"lifelong: packnet_prune must be in [0, 1), got {fraction!r}")
        owner = {}
        with torch.no_grad():
            for name, weight in linear_weights(net).items():
                mine = self.trainable(name)
                values = weight.detach().cpu()[mine].abs()
                rank = round(fraction * values.numel())
                mask = self.owner[name].clone()
                if rank > 0:
                    cutoff = values.kthvalue(rank).values
                    mask[mine & (weight.detach().cpu().abs() <= cutoff)] = 0
                weight[(mask == 0).to(weight.device)] = 0.0
                owner[name] = mask
        return WeightMasks(owner, self.task)

    def only_tasks_up_to(self, net: nn.Module, task: int) -> None:
        """Zero in `net` every weight that is free or owned by a task after `task`: the network task `task`
        is evaluated with."""
        with torch.no_grad():
            for name, weight in linear_weights(net).items():
                drop = (self.owner[name] == 0) | (self.owner[name] > task + 1)
                weight[drop.to(weight.device)] = 0.0

    def digest(self) -> str:
        return tensor_digest(self.owner) + f":{self.task}:{self.claim_free}"

    def save(self, path: str) -> None:
        _save(path, {"owner": self.owner})

    @classmethod
    def load(cls, path: str, task: int, claim_free: bool = False) -> WeightMasks:
        """The ownership saved at `path`, for `task` to train next (claiming the free weights if it starts)."""
        return cls(_load(path, ("owner",), "PackNet masks")["owner"], int(task), claim_free)
