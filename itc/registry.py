"""The four criteria by name, in the order every label array and file uses."""

from __future__ import annotations

from collections.abc import Sequence

from base_suites.runtime.errors import unknown_choice
from itc.alignment import Alignment
from itc.base import Constraint
from itc.collision import CollisionFree
from itc.params import ITCParams
from itc.pose_accuracy import PoseAccuracy
from itc.sequence import SequenceIntegrity
from itc.spec import ConstraintSpec

CONSTRAINTS: dict[str, type[Constraint]] = {
    cls.name: cls for cls in (SequenceIntegrity, PoseAccuracy, Alignment, CollisionFree)
}
CRITERIA: tuple[str, ...] = tuple(CONSTRAINTS)


def make_constraints(spec: ConstraintSpec, params: ITCParams, criteria: Sequence[str] = CRITERIA) -> list[Constraint]:
    """Instantiate constraints by criterion name."""
    for name in criteria:
        if name not in CONSTRAINTS:
            raise unknown_choice("ITC criterion", name, CRITERIA)
    return [CONSTRAINTS[name](spec, params) for name in criteria]
