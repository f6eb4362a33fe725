"""Record formats and their migrations (docs/design.md, errors and durability).

Every record the project writes and reads back (a run's config.json, a checkpoint, chain.json, a gate)
names its format, "name/version". Its code declares one `RecordFormat`: the current version and one
migration per version step, a function beside the record's code that turns a record of version v into
one of version v + 1. Reading a record upgrades it step by step to the current version, so the rest of
the code sees today's fields only. A record without a format field is version 1 (records carried none
at first); a record older than the migrations reach, of a newer version, or of another format is refused
in one line naming its format. A setting added with a version step gets, in that step, the value that
reproduces what older records' runs did; `NOT_RECORDED` marks one that did nothing before it existed,
which a comparison (`base_suites.runtime.io.changed_fields`) takes as equal to anything.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from base_suites.runtime.errors import UserInputError

NOT_RECORDED = "<not recorded>"


def fill_missing(record: dict[str, Any], values: Mapping[str, Any]) -> dict[str, Any]:
    """`record` with each of `values` set where it lacks it: a dict value fills a nested record the same
    way, a callable computes the value from the record. What a version step does for settings added."""
    for key, value in values.items():
        if isinstance(value, Mapping) and isinstance(record.get(key), dict):
            record[key] = fill_missing(dict(record[key]), value)
        elif callable(value):
            record.setdefault(key, value(record))
        else:
            record.setdefault(key, copy.deepcopy(value))
    return record


@dataclass(frozen=True)
class RecordFormat:
    """A record format: `name`, its current `version`, and `steps[v]` turning a version-v record into a
    version v + 1 one (a function of a copy of the record). Versions below the lowest step are refused."""

    name: str
    version: int
    steps: Mapping[int, Callable[[dict[str, Any]], dict[str, Any]]] = field(default_factory=dict)
    key: str = "format"  # the field that names the format

    @property
    def tag(self) -> str:
        """What a record of the current version holds in its format field."""
        return f"{self.name}/{self.version}"

    def version_of(self, record: Mapping[str, Any], where: str) -> int:
        """The version `record` says it has (1 without a format field), or one line refusing another format."""
        tag = record.get(self.key)
        if tag is None:
            return 1
        name, _, number = str(tag).rpartition("/")
        if name != self.name or not number.isdigit():
            raise UserInputError(f"{where}: field {self.key!r} is {tag!r}; expected {self.tag!r}")
        return int(number)

    def upgrade(self, record: Any, where: str) -> dict[str, Any]:
        """`record` as a record of the current version, through each migration step in turn."""
        if not isinstance(record, dict):
            raise UserInputError(f"{where}: expected a {self.name} record (a JSON object), got {type(record).__name__}")
        version = self.version_of(record, where)
        oldest = min(self.steps, default=self.version)
        found = f"field {self.key!r} is {record.get(self.key)!r}"
        if version > self.version:
            raise UserInputError(f"{where}: {found}, newer than this libero-elegant reads ({self.tag!r})")
        if version < oldest:
            raise UserInputError(
                f"{where}: {found} (version {version}), older than this libero-elegant migrates (from "
                f"{self.name}/{oldest}); write it again"
            )
        upgraded = copy.deepcopy(record)
        for step in range(version, self.version):
            upgraded = self.steps[step](upgraded)
        upgraded[self.key] = self.tag
        return upgraded
