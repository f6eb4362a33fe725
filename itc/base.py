"""The interface every ITC implements.

A constraint is stateful over one episode: `reset` sees the scene right after `env.reset` (after the
settle phase) and remembers what it needs (initial poses, which sub-goals already hold), then `check`
sees the state after each step and returns why the step violates the criterion (empty when kept). The
reasons name the objects and the measured value against its threshold, so a label can be audited.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

from itc.context import StepContext
from itc.params import ITCParams
from itc.spec import ConstraintSpec


class Constraint(ABC):
    """One implicit task constraint, evaluated per step from the simulator view only."""

    name: ClassVar[str]

    def __init__(self, spec: ConstraintSpec, params: ITCParams) -> None:
        self.spec = spec
        self.params = params

    @abstractmethod
    def reset(self, ctx: StepContext) -> None:
        """Forget the last episode and record the scene as it starts."""

    @abstractmethod
    def check(self, ctx: StepContext) -> list[str]:
        """Reasons the step that led to `ctx` violates this criterion; empty when it is kept."""


def cm(metres: float) -> str:
    return f"{metres * 100:.1f} cm"


def deg(radians: float) -> str:
    return f"{radians * 57.29577951308232:.1f} deg"
