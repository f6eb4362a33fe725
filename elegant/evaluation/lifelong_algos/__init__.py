"""LIBERO's lifelong algorithms as registered classes, one module each (`libero/lifelong/algos`;
docs/design.md §8.3).

Every staged algorithm learns task k from the network kept after task k-1 (task 0 from a fresh network
over the features of all K tasks). It differs from plain fine-tuning in LIBERO's hooks, which are
`LifelongAlgorithm`'s methods:

- `start_task(run, k)`: what the training step of stage k adds (`elegant.policies.continual`): nothing
  (SeqL), a replay memory of tasks 0..k-1 (ER), a penalty towards the weights kept after k-1 with their
  Fisher information (EWC), or the weights stage k may change (PackNet).
- `end_task(run, k, kept)`: after the best checkpoint of stage k is kept: EWC adds task k's Fisher
  information to the anchor; PackNet prunes the kept network and fine-tunes what is left.
- `earlier(run, k)`: the policy each earlier task is evaluated with after task k.

An algorithm's own settings are a frozen dataclass (`Settings`) declared in its module; `LifelongConfig`
takes each of them as the option `--{name}-{setting}` and the field `{name}_{setting}`, so records and
command lines keep one flat namespace. A subclass that sets `name` registers itself (as LIBERO's
`AlgoMeta` does), and the package imports every module in it: a new algorithm is one new file. Modules
import torch and the simulator only inside their hooks, so the CLI builds its options without them.
"""

from __future__ import annotations

import dataclasses
import importlib
import pkgutil
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from base_suites.runtime.errors import unknown_choice

if TYPE_CHECKING:
    from elegant.evaluation.lifelong_run import LifelongRun

_REGISTRY: dict[str, LifelongAlgorithm] = {}


class LifelongAlgorithm:
    """Plain sequential fine-tuning (SeqL), which every staged algorithm extends through its hooks.

    `name` registers a subclass; `title` names it in reports and in `--algo`'s help; `position` orders
    LIBERO's tables;
    `Settings` (None: none) is its own settings; `staged` False learns all tasks at once (multitask)."""

    name: ClassVar[str]
    title: ClassVar[str]
    position: ClassVar[int]
    Settings: ClassVar[type | None] = None
    staged: ClassVar[bool] = True

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "name" in cls.__dict__:
            if cls.name in _REGISTRY:
                raise ValueError(f"lifelong algorithm {cls.name!r} is registered twice")
            _REGISTRY[cls.name] = cls()

    # --- settings ---------------------------------------------------------------------------------------
    def settings_of(self, config: Any) -> Any:
        """This algorithm's settings as `config` (a `LifelongConfig`) holds them (None without any)."""
        if self.Settings is None:
            return None
        return self.Settings(**{f.name: getattr(config, self.field(f.name)) for f in dataclasses.fields(self.Settings)})

    def field(self, setting: str) -> str:
        """The `LifelongConfig` field (and recorded name) of one of its settings (a trailing underscore,
        as in `lambda_`, dropped)."""
        return f"{self.name}_{setting.rstrip('_')}"

    def check(self, settings: Any, config: Any) -> None:
        """Refuse, in one line, settings out of range or at odds with `config`'s (the protocol's epochs)."""

    def record(self, config: Any) -> dict[str, Any]:
        """The settings a run of this algorithm records (none of the other algorithms')."""
        settings = self.settings_of(config)
        return {} if settings is None else {self.field(k): v for k, v in dataclasses.asdict(settings).items()}

    def read(self, record: Mapping[str, Any]) -> Any:
        """The typed settings of a run's record (`record`'s output), so no stage indexes a dict."""
        if self.Settings is None:
            return None
        return self.Settings(**{f.name: record[self.field(f.name)] for f in dataclasses.fields(self.Settings)})

    # --- LIBERO's hooks ---------------------------------------------------------------------------------
    def start_task(self, run: LifelongRun, k: int) -> dict[str, Any]:
        """What stage k's training adds (`FineTuning`'s replay, anchor or masks); plain fine-tuning: nothing."""
        return {}

    def train_stage(self, run: LifelongRun, k: int) -> None:
        """Stage k: task k's demos, starting where task k-1 left the network, snapshots at the evaluation epochs."""
        from elegant.policies.bc_train import FineTuning

        cfg = run.config
        start = run.fresh_start() if k == 0 else {"init_from": run.kept[k - 1]}
        tune = FineTuning(
            tasks=[cfg["task_keys"][k]], snapshot_epochs=cfg["eval_epochs"], **start, **self.start_task(run, k)
        )
        run.train(run.stage_dir(k), tune, cfg["epochs"], cfg["task_keys"][k])

    def end_task(self, run: LifelongRun, k: int, kept: str) -> tuple[str, Any]:
        """The network task k leaves behind and its (success, ESR) on task k; None: that of `kept`."""
        return kept, None

    def earlier(self, run: LifelongRun, k: int) -> list[tuple[str, list[int], Path]]:
        """(policy, positions of earlier tasks, evaluation run directory) for S[k, :k]."""
        return [(run.kept[k], list(range(k)), run.out / "evals" / f"after_task_{k}")]


def lifelong_algorithm(name: str) -> LifelongAlgorithm:
    """The algorithm named `name`, or one line listing those there are."""
    if name not in _REGISTRY:
        raise unknown_choice("lifelong algorithm", name, algorithm_names())
    return _REGISTRY[name]


def algorithm_names() -> tuple[str, ...]:
    """Every registered algorithm's name, in the order LIBERO's tables list them."""
    return tuple(sorted(_REGISTRY, key=lambda name: _REGISTRY[name].position))


def settings_fields() -> list[tuple[str, Any, dataclasses.Field]]:
    """`LifelongConfig`'s fields for every algorithm's settings: ("{name}_{setting}", type, field), each
    with its setting's default, help and option `--{name}-{setting}`."""
    fields = []
    for name in algorithm_names():
        algorithm = _REGISTRY[name]
        if algorithm.Settings is None:
            continue
        hints = typing.get_type_hints(algorithm.Settings)
        for f in dataclasses.fields(algorithm.Settings):
            option = algorithm.field(f.name).replace("_", "-")
            metadata = {**f.metadata, "flag": f.metadata.get("flag") or f"--{option}"}
            default = dataclasses.field(default=f.default, metadata=metadata)
            fields.append((algorithm.field(f.name), hints[f.name], default))
    return fields


for _module in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
    importlib.import_module(f"{__name__}.{_module.name}")

__all__ = ["LifelongAlgorithm", "algorithm_names", "lifelong_algorithm", "settings_fields"]
