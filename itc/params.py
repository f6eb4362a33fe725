"""The thresholds of the four ITCs, as one documented, overridable dataclass.

Every number a constraint compares against lives here, so an annotation file can record exactly which
thresholds produced its labels, a per-task YAML override can change one of them, and nothing is tuned
by editing code. The defaults were calibrated on the real LIBERO scenes (see the field comments): a clean
scripted execution keeps every criterion, and the sloppy behaviours the scripted experts' quality knobs
produce (collide, drop, misplace, tilt, wrong order) break the matching one.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from base_suites.runtime.errors import UserInputError


@dataclass(frozen=True)
class ITCParams:
    """Thresholds of the constraints (SI units; angles in degrees)."""

    # -- sequence: objects the task does not name stay where they were, and fixtures it does not name too.
    distractor_move: float = 0.02
    """An unnamed object counts as disturbed once it is this far (m) from its pose at reset."""
    distractor_tilt_deg: float = 15.0
    """... or once its up axis has turned this far from where it pointed at reset."""
    fixture_slide: float = 0.02
    """An unnamed drawer (slide joint) counts as disturbed once it moved this far (m)."""
    fixture_hinge_deg: float = 15.0
    """An unnamed door or knob (hinge joint) counts as disturbed once it turned this far."""
    undo_grace_steps: int = 5
    """A reached sub-goal counts as undone after it has been false this many consecutive steps
    (LIBERO's contact-based predicates flicker for a step when an object settles)."""

    # -- pose accuracy: where a placed object comes to rest.
    place_xy_tolerance: float = 0.03
    """Largest xy distance (m) from the target's centre; LIBERO's own On() for objects uses 3 cm. The
    scripted expert places within ~1 cm; its `misplace` knob 5-8 cm off."""
    region_edge_margin: float = 0.02
    """Where several goal objects share one region, the tolerance per axis grows to the region's half
    size minus this margin (m), so two items fit in a basket while one hanging over the rim fails."""
    placement_radius: float = 0.12
    """A release whose resting point lies within this xy distance (m) of the target counts as a
    placement attempt there (farther away it is a put-down elsewhere, not a misplacement)."""
    beside_margin: float = 0.08
    """... and so does one resting this close (m, gap between xy bounding boxes) to a movable target (a
    basket, bowl or plate): set down beside the container it belongs in, it missed it. A basket's centre
    lies farther than `placement_radius` from an object standing against its outside. The expert's
    `misplace` aims 1.5 cm clear of the container; set down, or dropped, its objects rested 3.2-4.7 cm
    clear, and 7 cm with the `jerky` knob's shaking hand (label benchmark seed 1, libero_object/1)."""
    rest_speed: float = 0.02
    """An object is at rest below this linear speed (m/s) ..."""
    rest_steps: int = 3
    """... held for this many consecutive steps."""

    # -- alignment: upright objects stay upright; grasps approach along an object axis.
    upright_tolerance_deg: float = 20.0
    """A carried object, or an upright one, violates alignment when its up axis leans more than this.
    Measured with the scripted expert: clean carries lean at most 17 deg (a bowl swings in a rim grasp),
    its `tilt` knob 34-68 deg."""
    upright_arm_deg: float = 10.0
    """An object counts as standing upright (and is watched from then on) once it rests within this."""
    approach_tolerance_deg: float = 30.0
    """At grasp, the gripper's approach axis must be within this of an object axis (along or across it)."""

    # -- collision: robot and held object touch only what the task is about; nothing falls or slams.
    contact_force: float = 5.0
    """Total normal force (N) between the robot (or the held object) and an entity it should not touch.
    Measured: a finger brushing a bottle 1 N; pushing a 30 g box at 0.2 m/s 15-20 N; a grasp 2-6 N."""
    push_speed: float = 0.1
    """An object the robot (or the held object) should not touch may move at most this fast (m/s) while
    touching it. A sliding push barely loads the contact at the 20 Hz samples: a cream cheese box pushed
    along the table at 0.3 m/s by a finger showed 0.01 N, under any force threshold."""
    drop_height: float = 0.05
    """A released object may fall at most this far (m) before it touches something."""
    impact_speed: float = 1.0
    """An object may hit something at most this fast (m/s): the speed of a free fall from 5 cm."""

    # -- segment labels
    segment_length: int = 25
    """Frames per labelled window (LIBERO-Elegant's segment length)."""

    @property
    def distractor_tilt(self) -> float:
        return math.radians(self.distractor_tilt_deg)

    @property
    def fixture_hinge(self) -> float:
        return math.radians(self.fixture_hinge_deg)

    @property
    def upright_tolerance(self) -> float:
        return math.radians(self.upright_tolerance_deg)

    @property
    def upright_arm(self) -> float:
        return math.radians(self.upright_arm_deg)

    @property
    def approach_tolerance(self) -> float:
        return math.radians(self.approach_tolerance_deg)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def updated(self, changes: Mapping[str, Any], source: str = "ITC parameters") -> ITCParams:
        """A copy with some fields changed; unknown names or non-numbers are refused naming `source`."""
        fields = {f.name: f for f in dataclasses.fields(self)}
        clean: dict[str, Any] = {}
        for key, value in changes.items():
            if key not in fields:
                raise UserInputError(f"{source}: unknown ITC parameter {key!r}; expected one of: {', '.join(fields)}")
            want = int if fields[key].type in (int, "int") else float
            number = isinstance(value, (int, float)) and not isinstance(value, bool)
            if not number or (want is int and not float(value).is_integer()):
                kind = "an integer" if want is int else "a number"
                raise UserInputError(f"{source}: ITC parameter {key!r} must be {kind}, got {value!r}")
            least = 1 if key == "segment_length" else 0
            if value < least:
                raise UserInputError(f"{source}: ITC parameter {key!r} must be >= {least}, got {value!r}")
            clean[key] = want(value)
        return dataclasses.replace(self, **clean)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None, source: str = "ITC parameters") -> ITCParams:
        return cls().updated(data or {}, source)
