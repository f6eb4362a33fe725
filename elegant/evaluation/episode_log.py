"""RUN/episodes.jsonl, the append-only record of a run's finished episodes, and which of them a run counts.

Its own module because both the evaluation runner (which appends) and the reports (which pair the
episodes of several runs) read it, and the runner imports the reports.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from annotations.format import task_key
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import atomic_write


class EpisodeLog:
    """RUN/episodes.jsonl: finished episodes, one JSON line each, flushed as each finishes."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.records: list[dict[str, Any]] = []
        if path.exists():
            self._read()

    def _read(self) -> None:
        lines = self.path.read_text().split("\n")
        complete = lines[:-1]  # everything before the last newline; a crash may leave a partial last line
        for n, line in enumerate(complete, 1):
            try:
                self.records.append(json.loads(line))
            except json.JSONDecodeError:
                raise UserInputError(f"{self.path}: line {n} is not valid JSON; the run directory is damaged") from None
        if lines[-1]:
            atomic_write(self.path, "".join(line + "\n" for line in complete))

    def done(self) -> set[tuple[str, int]]:
        return {(r["task"], int(r["episode"])) for r in self.records}

    def append(self, record: dict[str, Any]) -> None:
        with open(self.path, "a") as f:
            f.write(json.dumps(record) + "\n")
            f.flush()
            os.fsync(f.fileno())
        self.records.append(record)


def run_records(records: Sequence[dict[str, Any]], config: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The records a run's metrics count: those of its tasks and its first `episodes` episodes (a run resumed
    with fewer episodes keeps the later ones in the log, but not in its numbers), in the run's task order
    and then by episode, whatever order they finished in (parallel workers finish out of order)."""
    order = {task_key(config["suite"], i): n for n, i in enumerate(config["tasks"])}
    counted = [r for r in records if r["task"] in order and int(r["episode"]) < int(config["episodes"])]
    return sorted(counted, key=lambda r: (order[r["task"]], int(r["episode"])))
