"""PEP 562 lazy exports: a package names its public API without importing heavy modules (torch, the
simulator) until a name is first used, which keeps `elegant --help` and light imports fast."""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_getattr(package: str, namespace: dict[str, Any], table: Mapping[str, str]) -> Callable[[str], Any]:
    """A module-level `__getattr__` resolving `table[name]` (a module path) on first access."""

    def __getattr__(name: str) -> Any:
        if name in table:
            value = getattr(importlib.import_module(table[name]), name)
            namespace[name] = value
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__
