"""Motion primitives as generators of OSC_POSE actions, read off the simulator at every step.

Each skill is a generator that yields one action per env step and returns whether it reached its aim,
so skills compose with `yield from` into task plans. Quality knobs (collide, drop, misplace, tilt,
jerky, regrasp) are applied inside the skills where the behaviour belongs.
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass, field

import numpy as np

from base_suites.experts.control import (
    CLOSE,
    OPEN,
    Servo,
    finger_axis,
    grasp_rotation,
    nearest_grasp_rotation,
    rot_z,
    rotation_error,
)
from base_suites.experts.geometry import (
    OVERHANG_GAP,
    Grasp,
    carry_height,
    choose_grasp,
    fill_boxes,
    floor_and_roof,
    headroom,
    narrowest_pinch,
    push_yaw,
    shape_of,
    slide_path,
    standing_points,
    way_out,
)
from base_suites.sim_view import GRIPPER, ROBOT, SimView

Actions = Generator[np.ndarray, None, bool]


LIFT = 0.10  # m a grasped object is lifted before it is carried off ...
MIN_LIFT = 0.01  # ... or, under an overhang, at least this far: clear of the table to be carried out sideways
LOW_CARRY = 0.01  # m above the table that `place(low=True)` carries an object's bottom
RELEASE_CLEARANCE = 0.02  # m the fingers open beyond the held width before the hand moves off


@dataclass
class SkillContext:
    """What every skill reads and writes: the sim view, the servo, the episode's knobs and RNG."""

    view: SimView
    rng: np.random.Generator
    knobs: set[str] = field(default_factory=set)
    servo: Servo = field(default_factory=Servo)
    events: list[str] = field(default_factory=list)

    def goto(
        self,
        pos,
        rot,
        grip: float,
        tol: float = 0.008,
        rot_tol: float = 0.06,
        max_steps: int = 120,
        speed: float = 1.0,
        until: Callable[[], bool] | None = None,
    ) -> Actions:
        """Servo the grip point to `pos` with orientation `rot`; True once within tolerance, or as soon as
        `until()` holds (a drawer pulled open need not reach a point past its end stop)."""
        self.servo.reset_integral()
        pos = np.asarray(pos, dtype=float)
        for _ in range(max_steps):
            if until is not None and until():
                return True
            pos_err = pos - self.view.eef_position()
            rot_err = rotation_error(rot, self.view.eef_rotation())
            if np.linalg.norm(pos_err) < tol and np.linalg.norm(rot_err) < rot_tol:
                return True
            yield self.servo.action(pos_err, rot_err, grip, speed)
        return False

    def hold(self, grip: float, steps: int, rot=None, until: Callable[[], bool] | None = None) -> Actions:
        """Stay in place (orientation `rot` or current) while commanding the gripper, for `steps` steps
        or until `until()` holds."""
        target = self.view.eef_position()
        rot = self.view.eef_rotation() if rot is None else rot
        self.servo.reset_integral()
        for _ in range(steps):
            if until is not None and until():
                break
            yield self.servo.action(
                target - self.view.eef_position(), rotation_error(rot, self.view.eef_rotation()), grip
            )
        return True

    def release(self, rot=None, clearance: float = RELEASE_CLEARANCE, max_steps: int = 10) -> Actions:
        """Open the gripper in place until the fingers stand `clearance` wider than they held: the hand
        can then leave without dragging what it let go, and no step waits for the full stroke (half of
        it, at LIBERO's 20 Hz, is a quarter second per placement)."""
        held = self.view.gripper_opening()
        return (
            yield from self.hold(OPEN, max_steps, rot, until=lambda: self.view.gripper_opening() >= held + clearance)
        )


def hand_down(
    view: SimView, yaw: float, at: np.ndarray | None = None, then: float = 0.0, shortest: bool = False
) -> np.ndarray:
    """The hand pointing down with grasp yaw `yaw`, turned so that the wrist stays off its stop when the
    hand gets to `at` (default: where it is) and, from there, turns `then` rad further about world z;
    `shortest`: of the two symmetric grasps, the one the hand turns to the short way."""
    base = view.robot_base_position()[:2]
    here = view.eef_position()[:2]
    there = here if at is None else np.asarray(at, dtype=float)[:2]
    swing = float(np.arctan2(*(there - base)[::-1]) - np.arctan2(*(here - base)[::-1]))
    return nearest_grasp_rotation(
        yaw, view.eef_rotation(), view.arm_joints()[6], then=then, swing=swing, shortest=shortest
    )


def _above(p: np.ndarray, z: float) -> np.ndarray:
    return np.array([p[0], p[1], z])


def pick(
    ctx: SkillContext,
    obj: str,
    attempts: int = 3,
    destination: np.ndarray | None = None,
    grasp_with: Callable[[SimView, str], Grasp | None] | None = None,
    lift: float = LIFT,
) -> Actions:
    """Top-down grasp of `obj` and lift by `lift` (m, less under an overhang); retries with a fresh
    grasp choice. The xy `destination` it will be carried to keeps the grasp one the arm can still set
    down there; `grasp_with` picks the grasp instead (a handle, for a carry through a doorway)."""
    view = ctx.view
    for attempt in range(attempts):
        grasp = (
            (grasp_with and grasp_with(view, obj))
            or choose_grasp(view, obj, destination=destination)
            or narrowest_pinch(view, obj)
        )
        rot = hand_down(view, grasp.yaw, at=grasp.position)
        hover = max(view.eef_position()[2], grasp.position[2] + 0.12)
        target = grasp.position.copy()
        if "regrasp" in ctx.knobs and attempt == 0:
            offset = finger_axis(grasp.yaw + np.pi / 2) * ctx.rng.uniform(0.03, 0.045)
            target = target + offset
            ctx.events.append("regrasp:miss")
        if view.eef_position()[2] < hover - 0.03:
            yield from ctx.goto(_above(view.eef_position(), hover), rot, OPEN, tol=0.03, rot_tol=0.3, max_steps=60)
        yield from ctx.goto(_above(target, hover), rot, OPEN, tol=0.02, rot_tol=0.1, max_steps=120)
        yield from ctx.goto(target + np.array([0, 0, 0.03]), rot, OPEN, tol=0.012, max_steps=60)
        yield from ctx.goto(target, rot, OPEN, tol=0.006, max_steps=40, speed=0.5)
        yield from ctx.hold(CLOSE, 12, rot)
        room = headroom(view, obj, grasp.yaw)  # what hangs over it still does once it is lifted
        lifted = _above(target, grasp.position[2] + float(np.clip(room - OVERHANG_GAP, MIN_LIFT, lift)))
        yield from ctx.goto(lifted, rot, CLOSE, tol=0.02, max_steps=40)
        if view.held_object() == obj:
            if np.isfinite(room):
                yield from _out_from_under(ctx, obj, grasp.yaw, rot)
            return True
        yield from ctx.hold(OPEN, 6, rot)
        ctx.events.append(f"pick:retry{attempt + 1}")
    return False


def _out_from_under(ctx: SkillContext, obj: str, yaw: float, rot: np.ndarray) -> Actions:
    """Carry the held `obj` sideways, at the height it was lifted to, until nothing hangs over it or
    the hand: rising straight up from under an opened drawer jams it against the drawer's bottom."""
    shift = way_out(ctx.view, obj, yaw)
    if shift is None:
        ctx.events.append("pick:trapped")
        return False
    destination = ctx.view.eef_position() + np.array([*shift, 0.0])
    return (yield from ctx.goto(destination, rot, CLOSE, tol=0.01, max_steps=40, speed=0.6))


def target_xy(view: SimView, target: str | np.ndarray, held: str | None = None, shared: bool = False) -> np.ndarray:
    """Where in xy an object goes for `target`: a point as given, a region's centre (or, for the `held`
    object, its free spot there), an object's position."""
    if not isinstance(target, str):
        return np.asarray(target, dtype=float)[:2]
    if target in view.regions:
        return _free_spot(view, target, held, shared) if held is not None else view.region(target).centre[:2]
    return view.position(target)[:2]


SHARED_OFFSET = 0.5  # first of several objects for one region: this far from its centre (x half size)
INNER = 0.7  # spots are searched this far out (x half size): the region's rim is the container's wall


def _free_spot(view: SimView, region_name: str, held: str, shared: bool, gap: float = 0.015) -> np.ndarray:
    """Where in a region the held object's footprint stays clear of what already stands there (both moka
    pots go on one burner; the container the region belongs to does not count): the clear spot nearest
    the region's centre, else the spot with the most room, within the inner part of the region. A region
    that several goal objects share gets its first object off-centre, leaving room for the next."""
    region = view.region(region_name)
    centre = region.centre[:2]
    axes, half = region.footprint()
    if half is None:
        return centre
    around = [o for o in view.objects if o not in (held, region.parent)]
    if any(view.joint_type(j) == "slide" for j in view.articulation_joints(region_name)):
        # A drawer: the cabinet above its back part (the drawer is only pulled out so far) counts too.
        around.append(region.parent)
    above = region.position[2] + 0.01
    boxes = np.concatenate([view.geom_points(o).reshape(-1, 8, 3) for o in around] or [np.zeros((0, 8, 3))])
    boxes = boxes[boxes[:, :, 2].max(axis=1) > above]
    others = fill_boxes(boxes)
    others = others[others[:, 2] > above][:, :2]
    if not len(others):
        return centre
    from scipy.spatial import cKDTree

    tree = cKDTree(others)
    # The footprint filled, not just its corners: a small object could otherwise sit inside it unseen.
    footprint = _footprint_xy(view.geom_points(held), view.position(held))
    if not np.all(np.abs((others - centre) @ axes) <= half, axis=1).any():
        if shared:
            long_axis = int(np.argmax(half))
            return centre + axes[:, long_axis] * SHARED_OFFSET * half[long_axis]
        if float(tree.query(footprint + centre)[0].min()) > gap:
            return centre
        # An object larger than the region (a plate in front of the stove) reaches beyond it, to what
        # stands around it: searched like a region that something stands in.
    grid = np.linspace(-INNER, INNER, 9)
    spots = [centre + axes @ (np.array([u, v]) * half) for u in grid for v in grid]
    for spot in sorted(spots, key=lambda p: float(np.linalg.norm(p - centre))):
        if float(tree.query(footprint + spot)[0].min()) > gap:
            return spot
    # The tight fit judges the footprint as the object will stand, not as it hangs tilted from its grasp
    # (the coarse search keeps the held footprint: judged upright, a bowl in libero_goal/3's drawer was
    # sent 3.6 cm off the centre, past the pose-accuracy limit, for the full gap).
    standing = _footprint_xy(standing_points(view, held), view.position(held))
    return _tightest_fit(boxes, above, standing, centre, axes, half)


SPOT_RESOLUTION = 0.0025  # m between the spots, and between the obstacle points, of a tight fit
OFF_CENTRE_COST = 0.05  # m of room a tight fit gives up per m nearer the region's centre (1 mm per 2 cm)


FOOTPRINT_CELL = 0.0005  # m: an object's filled footprint keeps one point per square this size


def _footprint_xy(corners: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """An object's filled footprint (xy, relative to its `origin`) from its box corners (8 per box)."""
    return _xy(fill_boxes(corners.reshape(-1, 8, 3)), FOOTPRINT_CELL) - origin[:2]


def _xy(points: np.ndarray, cell: float) -> np.ndarray:
    """The points' xy, one per `cell`-sized square: a filled box's layers above each other (and points
    closer than the precision needed) only multiply the cost of measuring room."""
    return np.unique(np.round(points[:, :2] / cell), axis=0) * cell


def _tightest_fit(
    boxes: np.ndarray, above: float, standing: np.ndarray, centre: np.ndarray, axes: np.ndarray, half: np.ndarray
) -> np.ndarray:
    """The spot in the region whose footprint keeps the most room, measured exactly enough for a fit
    with millimetres to spare (a 10.7 cm bowl into the 11.6 cm of drawer a cabinet leaves exposed). The
    coarse search measures room between point lattices, which cannot tell a footprint 3 mm clear of an
    obstacle from one 3 mm into it, and samples a drawer's 22 cm front panel at three points along its
    length; here the obstacles are sampled every few millimetres and room is signed: the distance from
    each obstacle point to the edges of the footprint's convex hull, negative inside it. The region's
    own rim counts as well (a basket's wall, which is not among the obstacles): pushed only away from
    what stands in a basket, a box ended up on its rim."""
    from scipy.spatial import ConvexHull

    hull = ConvexHull(standing)
    normals, offsets = hull.equations[:, :2], hull.equations[:, 2]
    reach = float(np.linalg.norm(standing, axis=1).max())
    obstacles = fill_boxes(boxes, spacing=SPOT_RESOLUTION * 4)
    obstacles = _xy(obstacles[obstacles[:, 2] > above], SPOT_RESOLUTION)
    near = obstacles[np.all(np.abs((obstacles - centre) @ axes) <= INNER * half + reach, axis=1)]
    if not len(near):
        return centre

    outline = standing[hull.vertices] @ axes  # hull corners in the region's axes, about the spot

    def roomiest(spots: np.ndarray) -> np.ndarray:
        """The spot with the most room, less `OFF_CENTRE_COST` of it per metre off the region's centre
        (pose accuracy: a drawer's widest gap may lie at its side)."""
        rooms = np.array([((near - spot) @ normals.T + offsets).max(axis=1).min() for spot in spots])
        inside = (half - np.abs(outline[None] + ((spots - centre) @ axes)[:, None])).min(axis=(1, 2))
        return spots[
            int(np.argmax(np.minimum(rooms, inside) - OFF_CENTRE_COST * np.linalg.norm(spots - centre, axis=1)))
        ]

    coarse = [np.arange(-INNER * h, INNER * h + 1e-9, 2 * SPOT_RESOLUTION) for h in half]
    best = roomiest(np.array([centre + axes @ np.array([u, v]) for u in coarse[0] for v in coarse[1]]))
    fine = np.arange(-2, 3) * SPOT_RESOLUTION / 2
    return roomiest(np.array([best + axes @ np.array([u, v]) for u in fine for v in fine]))


APPROACH_CLEARANCE = 0.04  # m above its support where a set-down slows to the touch-down speed
MISPLACE_OFFSET = (0.05, 0.08)  # the misplace knob sets objects down this far from their goal spot (m)
# The drop knob lets go with the object's bottom this high above what lies below (m): twice the ITC's
# 5 cm drop limit. The carrying height alone leaves only its 5 cm margin over a tall target.
DROP_CLEARANCE = 0.10
MISPLACE_CLEARANCE = 0.015  # ... or this far clear of the container the goal region belongs to
MISPLACE_REACHED = 0.06  # the object let go within this xy distance of the wrong spot was misplaced there


def _misplaced_xy(ctx: SkillContext, target: str, held: str, goal_xy: np.ndarray) -> np.ndarray:
    """The wrong spot for the misplace knob: 5-8 cm off the goal, in a random direction. A goal on or in a
    movable object (basket, bowl, plate) gets its object set down beside that object instead: a basket's
    sloped wall funnels an object released 5-8 cm off-centre back to its middle, undoing the knob."""
    view = ctx.view
    angle = ctx.rng.uniform(0, 2 * np.pi)
    direction = np.array([np.cos(angle), np.sin(angle)])
    distance = ctx.rng.uniform(*MISPLACE_OFFSET)
    container = view.region(target).parent if target in view.regions else target
    if container in view.objects:
        beyond_wall = float(np.max((view.geom_points(container)[:, :2] - goal_xy) @ direction))
        held_reach = float(np.max((view.geom_points(held)[:, :2] - view.position(held)[:2]) @ -direction))
        distance = max(distance, beyond_wall + held_reach + MISPLACE_CLEARANCE)
    return goal_xy + distance * direction


def _over(view: SimView, obj: str, spot_xy: np.ndarray) -> bool:
    """Whether `obj` hangs over (within `MISPLACE_REACHED` of) the spot in xy."""
    return bool(np.linalg.norm(view.position(obj)[:2] - spot_xy) < MISPLACE_REACHED)


def _tilt_rotation(ctx: SkillContext, yaw: float, angle: float) -> np.ndarray:
    # Tilt about the horizontal axis across the fingers: the held object swings out of upright.
    axis = np.cross(finger_axis(yaw), [0.0, 0.0, 1.0])
    return grasp_rotation(yaw, axis, angle)


def _set_down(view: SimView, obj: str) -> bool:
    """Whether the held `obj` touches anything but the robot with its lower half: it has reached what
    it is set down on. A touch higher up is something it passes under (the handle of the drawer above
    the one a bowl goes into, brushed by its rim): letting go there dropped the bowl 13 cm."""
    touches = [c.position[2] for c in view.contacts() if c.involves(obj) and c.other(obj) not in (GRIPPER, ROBOT)]
    if not touches:  # the common case on the way down: no need to measure the object
        return False
    shape = shape_of(view, obj)
    return min(touches) < (shape.bottom + shape.top) / 2


def place(ctx: SkillContext, obj: str, target: str | np.ndarray, shared: bool = False, low: bool = False) -> Actions:
    """Carry the held `obj` above `target` (a region, an entity or an xy point) and set it down on contact.
    `shared`: other goal objects go to the same region (see `_free_spot`); `low`: a move straight away
    from what the object stood against, carried `LOW_CARRY` above only what lies ahead of it."""
    view = ctx.view
    rot = view.eef_rotation()
    yaw = float(np.arctan2(rot[1, 0], rot[0, 0]) - np.pi / 2)
    upright = grasp_rotation(yaw)
    goal_xy = target_xy(view, target, held=obj, shared=shared)
    # The misplace event is recorded at the release over the wrong spot, not when the offset is drawn:
    # an episode that times out before letting go (after a knock, a long regrasp) misplaced nothing, nor
    # does one whose shaking (`jerky`) carry let go far short of the wrong spot: it failed to carry.
    misplaced = "misplace" in ctx.knobs and isinstance(target, str)
    if misplaced:
        goal_xy = _misplaced_xy(ctx, target, obj, goal_xy)
    z_carry = (
        carry_height(view, obj, goal_xy, margin=LOW_CARRY, ahead_only=True) if low else carry_height(view, obj, goal_xy)
    )
    carry_rot = upright
    if "tilt" in ctx.knobs and isinstance(target, str):
        carry_rot = _tilt_rotation(ctx, yaw, np.deg2rad(ctx.rng.uniform(40, 60)))
        ctx.events.append("tilt")
    yield from ctx.goto(_above(view.eef_position(), z_carry), carry_rot, CLOSE, tol=0.03, rot_tol=0.2, max_steps=60)
    # Aim the *object* at the goal: correct for where it sits in the hand.
    for _ in range(3):
        offset = view.position(obj)[:2] - view.eef_position()[:2]
        yield from ctx.goto(
            np.array([*(goal_xy - offset), z_carry]), carry_rot, CLOSE, tol=0.01, rot_tol=0.1, max_steps=60
        )
        if np.linalg.norm(view.position(obj)[:2] - goal_xy) < 0.015:
            break
    if carry_rot is not upright:
        yield from ctx.goto(view.eef_position(), upright, CLOSE, tol=0.02, rot_tol=0.06, max_steps=40)
    if "drop" in ctx.knobs and isinstance(target, str):
        release_z = carry_height(view, obj, goal_xy, margin=DROP_CLEARANCE)
        if view.eef_position()[2] < release_z:
            yield from ctx.goto(
                _above(view.eef_position(), release_z), upright, CLOSE, tol=0.015, rot_tol=0.1, max_steps=40
            )
        ctx.events.extend(["misplace", "drop"] if misplaced and _over(view, obj, goal_xy) else ["drop"])
        yield from ctx.hold(OPEN, 10)
        yield from ctx.hold(OPEN, 10)
        return True
    # Descend until the held object touches its support (or anything but the robot): at full speed
    # down to `APPROACH_CLEARANCE` above what stands below (a carry over a cabinet starts 30 cm up, which
    # at the touch-down speed alone took 70 steps), slowly from there. Only go down while the object is
    # over its goal: correcting sideways first keeps it off rims and handles it would be set down on.
    slow_below = carry_height(view, obj, goal_xy, margin=APPROACH_CLEARANCE)
    ctx.servo.reset_integral()
    for _ in range(150):
        xy_error = goal_xy - view.position(obj)[:2]
        aligned = np.linalg.norm(xy_error) < 0.015
        if _set_down(view, obj) and np.linalg.norm(xy_error) < 0.03:
            break
        high = view.eef_position()[2] - slow_below
        down = -(high + 0.02) if high > 0 else -0.02
        yield ctx.servo.action(
            np.array([*xy_error, down if aligned else 0.0]),
            rotation_error(upright, view.eef_rotation()),
            CLOSE,
            speed=1.0 if high > 0 else 0.35,
        )
    if misplaced and _over(view, obj, goal_xy):
        ctx.events.append("misplace")
    yield from ctx.release(upright)
    up = view.eef_position() + np.array([0, 0, 0.10])
    yield from ctx.goto(up, upright, OPEN, tol=0.02, max_steps=30)
    return True


SILL_CLEARANCE = 0.025  # m above the doorway's floor that an object is carried in
HAND_OUTSIDE = 0.04  # m the grip point stays outside a doorway's plane: the hand's half thickness and a margin


def insert(ctx: SkillContext, obj: str, target: str, facing: np.ndarray, front: float) -> Actions:
    """Carry the held `obj` into region `target` through a doorway that faces `facing` (horizontal) with
    its plane at `front` along it, and set it down there. The hand holds the object's trailing part (a
    mug by its handle) and turns it to trail outward; it comes down outside the doorway to just above
    the floor and slides the object in, stopping outside the doorway's plane itself: the roof above
    it leaves no room for a hand over the object."""
    view = ctx.view
    region = view.region(target)
    grip, origin = view.eef_position(), view.position(obj)
    trail = grip[:2] - origin[:2]
    turn = float(np.arctan2(facing[1], facing[0]) - np.arctan2(trail[1], trail[0]))
    rot = rot_z((turn + np.pi) % (2 * np.pi) - np.pi) @ view.eef_rotation()
    floor, _ = floor_and_roof(view, target)
    points = view.geom_points(obj)
    radius = float(np.max(np.linalg.norm(points[:, :2] - grip[:2], axis=1)))
    z = floor + SILL_CLEARANCE + grip[2] - float(points[:, 2].min())
    lateral = region.position[:2] - facing[:2] * float(region.position[:2] @ facing[:2])
    inside = np.array([*(lateral + facing[:2] * (front + HAND_OUTSIDE)), z])
    outside = np.array([*(lateral + facing[:2] * (front + radius + 0.02)), z])
    carry = max(view.eef_position()[2], carry_height(view, obj, outside[:2]))
    yield from ctx.goto(_above(outside, carry), rot, CLOSE, tol=0.02, rot_tol=0.1, max_steps=120)
    yield from ctx.goto(outside, rot, CLOSE, tol=0.01, max_steps=60)
    yield from ctx.goto(inside, rot, CLOSE, tol=0.004, max_steps=80, speed=0.35)
    yield from ctx.goto(
        inside - [0.0, 0.0, SILL_CLEARANCE + 0.01],
        rot,
        CLOSE,
        tol=0.006,
        max_steps=30,
        speed=0.35,
        until=lambda: _set_down(view, obj),
    )
    yield from ctx.release(rot)
    yield from ctx.goto(view.eef_position() + np.array([*(facing[:2] * 0.06), 0.0]), rot, OPEN, tol=0.02, max_steps=30)
    return True


def knock(ctx: SkillContext, victim: str) -> Actions:
    """Sweep the closed hand through a distractor at mid height (the `collide` knob)."""
    view = ctx.view
    shape = shape_of(view, victim)
    z = shape.bottom + max(0.6 * shape.height, 0.02)
    centre = shape.centre
    direction = centre[:2] - view.eef_position()[:2]
    direction = direction / max(np.linalg.norm(direction), 1e-6)
    start = np.array([*(centre[:2] - 0.10 * direction), z])
    end = np.array([*(centre[:2] + 0.06 * direction), z])
    rot = grasp_rotation(0.0)
    ctx.events.append(f"collide:{victim}")
    yield from ctx.goto(
        _above(start, max(view.eef_position()[2], shape.top + 0.08)), rot, CLOSE, tol=0.02, max_steps=80
    )
    yield from ctx.goto(start, rot, CLOSE, tol=0.015, max_steps=60)
    yield from ctx.goto(end, rot, CLOSE, tol=0.02, max_steps=40)
    yield from ctx.goto(_above(end, shape.top + 0.10), rot, OPEN, tol=0.03, max_steps=40)
    return True


# m inside its leading rim where the fingertips' leading face presses a pushed dish: over its foot. Out on
# the rim, beyond the foot, the press tips the dish up about the foot's edge and the fingers ride over it.
RIM_INSET = 0.034
CLOSED_FINGERS_HALF_SPAN = 0.024  # m the closed fingertips reach from the grip point along their closing axis
FINGER_HALF_DEPTH = 0.014  # ... and across it
PUSH_SPEED = 0.7
PRESS_DEPTH = 0.01  # m below where they touched the floor that the fingertips are held: a light press
RECONTACT = 0.03  # m the fingertips may drift off their press point before they are set down again
LOOKAHEAD = 0.04  # m along the path ahead of the object that it is steered towards


def push(ctx: SkillContext, obj: str, target: str, tolerance: float = 0.015, max_steps: int = 250) -> Actions:
    """Slide a flat object (a plate) over the table to `target` along `slide_path`, around what stands
    in the way, steered towards a point `LOOKAHEAD` ahead on that path. The closed fingertips press on
    the dish's floor just short of its leading rim: the floor drags it and the rim's gently sloped inner
    wall takes the push where the floor slips. Pressed beyond its foot, out on the rim, a plate tips
    up about the foot's edge and rides over the fingers. Coming down from above keeps the hand clear of
    the tall fixtures that often stand behind such objects; the hand's yaw is `push_yaw`'s."""
    view = ctx.view
    shape = shape_of(view, obj)
    press_z = shape.bottom + 0.004
    hover = shape.top + 0.03
    footprint = view.geom_points(obj)[:, :2] - view.position(obj)[:2]
    goal_xy = target_xy(view, target, held=obj)
    path = [view.position(obj)[:2]] + slide_path(view, obj, goal_xy)
    rot, floor, pressing = None, press_z, False
    for _ in range(max_steps):
        obj_xy = view.position(obj)[:2]
        if np.linalg.norm(goal_xy - obj_xy) < tolerance * 0.6:
            break
        ahead = _lookahead(path, obj_xy, LOOKAHEAD)
        direction = (ahead - obj_xy) / max(np.linalg.norm(ahead - obj_xy), 1e-6)
        reach = _press_reach(footprint, direction)
        if rot is None:  # one hand orientation for the whole push: turning it costs more than any gain
            rot = hand_down(view, push_yaw(view, obj, obj_xy + direction * reach, direction, press_z), at=obj_xy)
        press = obj_xy + direction * (reach - _fingertip_reach(rot, direction))
        eef = view.eef_position()
        if not pressing or eef[2] > shape.top + 0.01 or np.linalg.norm(eef[:2] - press) > RECONTACT:
            if eef[2] < hover - 0.01:
                yield from ctx.goto(_above(eef, hover), view.eef_rotation(), CLOSE, tol=0.01, max_steps=20)
            yield from ctx.goto(
                _above(press, max(view.eef_position()[2], hover)), rot, CLOSE, tol=0.015, rot_tol=0.15, max_steps=80
            )
            yield from ctx.goto(_above(press, hover), rot, CLOSE, tol=0.01, max_steps=40)
            touching = lambda: any(c.involves(obj) and c.other(obj) == "gripper" for c in view.contacts())  # noqa: E731
            yield from ctx.goto(_above(press, press_z), rot, CLOSE, tol=0.006, max_steps=30, speed=0.5, until=touching)
            floor, pressing = view.eef_position()[2] - PRESS_DEPTH, True
            ctx.servo.reset_integral()
            continue
        step = min(float(np.linalg.norm(goal_xy - obj_xy)), LOOKAHEAD)
        aim = np.array([*(press + direction * step), floor])
        ctx.servo.reset_integral()  # proportional only: the push is steered by where the object goes
        yield ctx.servo.action(aim - eef, rotation_error(rot, view.eef_rotation()), CLOSE, speed=PUSH_SPEED)
    yield from ctx.goto(_above(view.eef_position(), hover + 0.05), view.eef_rotation(), CLOSE, tol=0.02, max_steps=30)
    return bool(np.linalg.norm(goal_xy - view.position(obj)[:2]) < tolerance)


def _press_reach(footprint: np.ndarray, direction: np.ndarray) -> float:
    """How far from a dish's centre, towards `direction`, the fingertips' leading face presses."""
    return float(np.max(footprint @ direction)) - RIM_INSET


def _fingertip_reach(rot: np.ndarray, direction: np.ndarray) -> float:
    """How far the closed fingertips reach from the grip point towards the horizontal `direction` for
    the hand orientation `rot` (its x axis is the fingers' closing axis)."""
    closing, across = rot[:2, 0], rot[:2, 1]
    return float(abs(closing @ direction) * CLOSED_FINGERS_HALF_SPAN + abs(across @ direction) * FINGER_HALF_DEPTH)


def _lookahead(path: list[np.ndarray], point: np.ndarray, distance: float) -> np.ndarray:
    """The point `distance` further along the polyline `path` than the path's point nearest `point`."""
    legs = list(zip(path, path[1:]))
    feet = [
        a + float(np.clip((point - a) @ (b - a) / max(float((b - a) @ (b - a)), 1e-12), 0.0, 1.0)) * (b - a)
        for a, b in legs
    ]
    leg = int(np.argmin([np.linalg.norm(foot - point) for foot in feet]))
    left, here = distance, feet[leg]
    for _, b in legs[leg:]:
        span = float(np.linalg.norm(b - here))
        if span >= left:
            return here + (b - here) * (left / max(span, 1e-12))
        left -= span
        here = b
    return path[-1]


def can_grasp(view: SimView, obj: str) -> bool:
    """Whether a top-down grasp exists (flat wide objects such as plates must be pushed instead)."""
    return choose_grasp(view, obj) is not None
