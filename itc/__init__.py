"""Implicit Task Constraints: per-step evaluation from simulator state, segment labels, elegance reward."""

from itc.base import Constraint
from itc.monitor import EpisodeVerdict, ITCMonitor, StepResult
from itc.params import ITCParams
from itc.registry import CONSTRAINTS, CRITERIA, make_constraints
from itc.segments import num_windows, segment_labels, window_bounds
from itc.spec import ConstraintSpec, Placement, derive_spec, describe_spec
from itc.wrapper import ITCWrapper

__all__ = [
    "CONSTRAINTS",
    "CRITERIA",
    "Constraint",
    "ConstraintSpec",
    "EpisodeVerdict",
    "ITCMonitor",
    "ITCParams",
    "ITCWrapper",
    "Placement",
    "StepResult",
    "derive_spec",
    "describe_spec",
    "make_constraints",
    "num_windows",
    "segment_labels",
    "window_bounds",
]
