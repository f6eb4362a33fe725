"""JITI's modes, one registered object each (docs/design.md, JITI).

A mode says when JITI draws and re-ranks candidates (its trigger), which candidate runs (its selector),
whether it needs a critic or more than the `Policy` protocol from the base policy, which `JITIConfig`
settings its decisions depend on (what a run records and is compared on), and how a report names it.
Each mode lives in one module of this package and registers itself with `register_mode`; the package
imports every module in it, so a new mode is one new file.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass
from typing import Any

from base_suites.runtime.errors import UserInputError, unknown_choice
from elegant.intervention.selectors import Selector
from elegant.intervention.triggers import Trigger

# the settings of every mode that draws candidates
CANDIDATE_SETTINGS: tuple[str, ...] = ("n_candidates", "noise_scale", "trust_radius")


@dataclass(frozen=True)
class JITIMode:
    """One mode. `trigger(config, random_steps)` and `selector(config)` build its parts from a `JITIConfig`
    (`random_steps`: the steps a recorded rollout explores at, None for the config's own); `check(config)`
    refuses settings that contradict each other in this mode; `describe(record, candidates)` is the report's
    line for a run's recorded settings, `candidates` already saying how candidates were drawn."""

    name: str
    help: str
    settings: tuple[str, ...]
    trigger: Callable[[Any, Collection[int] | None], Trigger]
    selector: Callable[[Any], Selector]
    describe: Callable[[Mapping[str, Any], str], str]
    needs_critic: bool
    uses_window: bool = False  # scores the window of past decisions (logs m_t, its std and tau)
    policy_needs: tuple[str, ...] = ()  # methods the base policy must have beyond the `Policy` protocol
    check: Callable[[Any], None] | None = None


_REGISTRY: dict[str, JITIMode] = {}


def register_mode(mode: JITIMode) -> JITIMode:
    """Add `mode` to the registry (a second mode of one name is a programming error)."""
    if mode.name in _REGISTRY:
        raise ValueError(f"JITI mode {mode.name!r} is registered twice")
    _REGISTRY[mode.name] = mode
    return mode


def jiti_mode(name: str) -> JITIMode:
    """The mode named `name`, or one line listing the modes there are."""
    if name not in _REGISTRY:
        raise unknown_choice("JITI mode", name, _REGISTRY)
    return _REGISTRY[name]


def mode_names() -> tuple[str, ...]:
    """Every registered mode's name."""
    return tuple(_REGISTRY)


def check_policy(mode: JITIMode, policy: Any) -> None:
    """Refuse, in one line, a base policy that lacks what `mode` asks of it."""
    missing = [name for name in mode.policy_needs if not callable(getattr(policy, name, None))]
    if missing:
        raise UserInputError(
            f"JITI mode {mode.name!r} needs a base policy with {', '.join(missing)}; {type(policy).__name__} has none"
        )


for _module in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
    importlib.import_module(f"{__name__}.{_module.name}")

__all__ = ["CANDIDATE_SETTINGS", "JITIMode", "check_policy", "jiti_mode", "mode_names", "register_mode"]
