"""ER: every batch of task k is joined by as many samples of the memory of tasks 0..k-1 (LIBERO's ER)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from base_suites.runtime.errors import UserInputError
from base_suites.runtime.settings import setting
from elegant.evaluation.lifelong_algos import LifelongAlgorithm

if TYPE_CHECKING:
    from elegant.evaluation.lifelong_run import LifelongRun


@dataclass(frozen=True)
class ERSettings:
    memory: int = setting(1000, "ER: samples kept per earlier task (LIBERO's n_memories)")


class ExperienceReplay(LifelongAlgorithm):
    name = "er"
    title = "experience replay (ER)"
    position = 1
    Settings = ERSettings

    def check(self, settings: ERSettings, config: Any) -> None:
        if settings.memory < 1 or int(settings.memory) != settings.memory:
            raise UserInputError(f"lifelong: er_memory must be a positive integer, got {settings.memory!r}")

    def start_task(self, run: LifelongRun, k: int) -> dict[str, Any]:
        from elegant.policies.continual import replay_memory

        if k == 0:
            return {}
        return {"replay": replay_memory(run.data, run.config["task_keys"][:k], run.settings.memory)}
