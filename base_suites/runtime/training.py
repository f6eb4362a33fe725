"""One resumable training skeleton for the critic and the policy (docs/design.md, errors and durability).

A `Trainer` owns what both trainings share: the output directory's lock, clearing an earlier run's
results on `overwrite`, resuming from the last checkpoint, the progress bar, atomic checkpoints at the
units the run asks for, and publishing last. A run (`Training`) brings its own units (gradient steps for
the critic, epochs for the policy), its checkpoint's contents, what a checkpoint must match to be
resumed, and what it publishes. A run killed at any point and resumed continues from its last
checkpoint to the same numbers as an uninterrupted run, since every random state it draws from is in the
checkpoint. torch is imported on first use, so the CLI stays light.
"""

from __future__ import annotations

import io
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol

from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import atomic_write
from base_suites.runtime.locks import output_lock
from base_suites.runtime.outputs import remove_results


def torch_bytes(obj: Any) -> bytes:
    """`obj` as `torch.save` writes it."""
    import torch

    buffer = io.BytesIO()
    torch.save(obj, buffer)
    return buffer.getvalue()


def atomic_torch_save(path: str, obj: Any) -> None:
    """torch.save through `atomic_write`: a kill mid-write leaves the previous file intact."""
    atomic_write(path, torch_bytes(obj))


def read_checkpoint(path: str) -> dict[str, Any]:
    """A checkpoint's contents, read without running code (`weights_only`); a truncated, garbled or
    foreign file is refused in one line."""
    import torch

    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # a truncated or foreign file surfaces as many exception types
        raise UserInputError(
            f"{path}: unreadable checkpoint ({exc.__class__.__name__}); delete it to start over"
        ) from None
    if not isinstance(state, dict):
        raise UserInputError(f"{path}: not a training checkpoint (expected a mapping, got {type(state).__name__})")
    return state


class Progress(Protocol):
    def update(self, n: int = 1) -> Any: ...

    def set_postfix(
        self, ordered_dict: Mapping[str, Any] | None = None, refresh: bool = True, **kwargs: Any
    ) -> Any: ...


class Training(Protocol):
    """One run a `Trainer` drives, its units numbered 1..total.

    `resume(state, path)` checks that a checkpoint belongs to this run (one line naming the field that
    differs), restores it, and returns the units it holds. `begin(start)` runs once the directory is
    ready, before unit start + 1. `unit(n, bar)` trains unit n, advancing the bar. `checkpoint(n)` is
    the state to save after unit n, or None where no checkpoint is due. `checkpointed(n)` runs once it
    is on disk. `finish(start)` publishes and returns the run's summary."""

    def resume(self, state: dict[str, Any], path: str) -> int: ...

    def begin(self, start: int) -> None: ...

    def unit(self, n: int, bar: Progress) -> None: ...

    def checkpoint(self, n: int) -> dict[str, Any] | None: ...

    def checkpointed(self, n: int) -> None: ...

    def finish(self, start: int) -> dict[str, Any]: ...


@dataclass(frozen=True)
class Trainer:
    """Drives a `Training` in `out`: `what` names the command in the bar, `checkpoint_file` and `results`
    (the files an earlier run leaves, removed on `overwrite`) live in `out`; `total` units of
    `bar_per_unit` bar steps each (a batch per step of the bar for an epoch)."""

    what: str
    out: str
    checkpoint_file: str
    results: tuple[str, ...]
    total: int
    bar_per_unit: int = 1
    bar_unit: str = "step"

    @property
    def checkpoint_path(self) -> str:
        return os.path.join(self.out, self.checkpoint_file)

    def run(self, training: Training, *, resume: bool, overwrite: bool, progress: bool) -> dict[str, Any]:
        """Train (or continue) to `total` units with the directory's lock held; returns `finish`'s summary.
        The caller has checked the directory (`check_output`) and its inputs before: a refused input
        leaves nothing behind."""
        from tqdm.auto import tqdm

        with output_lock(self.out):  # one writer per directory
            os.makedirs(self.out, exist_ok=True)
            if overwrite:  # the earlier run's results and checkpoint go before this run writes its own
                remove_results(self.out, self.results)
            start = 0
            if resume and os.path.exists(self.checkpoint_path):
                start = training.resume(read_checkpoint(self.checkpoint_path), self.checkpoint_path)
            training.begin(start)
            with tqdm(
                total=self.total * self.bar_per_unit,
                initial=start * self.bar_per_unit,
                disable=not progress,
                desc=self.what,
                unit=self.bar_unit,
            ) as bar:
                for n in range(start + 1, self.total + 1):
                    training.unit(n, bar)
                    state = training.checkpoint(n)
                    if state is not None:
                        atomic_torch_save(self.checkpoint_path, state)
                        training.checkpointed(n)
            return training.finish(start)
