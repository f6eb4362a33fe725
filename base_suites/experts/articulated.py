"""Skills for articulated fixtures: drawers (slide joints), doors (hinges), stove knobs.

Drawers are pulled by their handle with the hand horizontal and the fingers pinching the handle bar
from above and below, then pushed shut with the closed fingertips on the drawer front, the hand pointing
down. Doors swing along the arc of their free edge, opening the way LIBERO's own open ranges say. Knobs
are grasped by their grip bar and turned by rotating the wrist about the knob's vertical hinge.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from base_suites.experts.control import CLOSE, OPEN, grasp_rotation, pitched_down, rot_axis, rot_z, rotation_error
from base_suites.experts.geometry import choose_grasp, fill_boxes, floor_and_roof
from base_suites.experts.skills import Actions, SkillContext, hand_down
from base_suites.sim_view import SimView


def container_of(view: SimView, target: str) -> str | None:
    """The articulated entity whose joint must be open before something can go into `target`."""
    if target in view.regions and view.articulation_joints(target):
        return view.region(target).parent
    return None


def is_open(view: SimView, target: str) -> bool:
    """Whether what must be open before something goes into region `target` is: a drawer region is
    asked itself, a region inside a hinged fixture (which LIBERO always calls shut) asks the fixture."""
    return view.predicate(("open", target if view.region_joints(target) else _fixture(view, target)))


def _fixture(view: SimView, target: str) -> str:
    """The articulated fixture a target names: a drawer region's cabinet, or the target itself."""
    return view.region(target).parent if target in view.regions else target


def _hand_facing(direction: np.ndarray, roll: float) -> np.ndarray:
    """Rotation with the gripper pointing along `direction` (horizontal), fingers closing vertically,
    or `roll` rad away from vertical about the pointing axis."""
    z = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    up = np.array([0.0, 0.0, 1.0])
    side = np.cross(z, up)
    x = np.cos(roll) * up + np.sin(roll) * side
    return np.column_stack([x, np.cross(z, x), z])


def _slide(view: SimView, target: str) -> tuple[str, np.ndarray, np.ndarray]:
    """The drawer joint, the world direction it opens in, and its handle point."""
    joint = view.articulation_joints(target)[0]
    info = view.joint(joint)
    entity = _fixture(view, target)
    opening = view.opening_sign(entity) * info["axis"]
    opening[2] = 0.0
    opening /= np.linalg.norm(opening)
    pts = view.geom_points(entity, body=info["body"])
    reach = pts @ opening
    front = pts[reach >= reach.max() - 0.012]
    handle = front.mean(axis=0)
    return joint, opening, handle


def _drawer_joint(view: SimView, target: str) -> dict | None:
    """`SimView.joint` of the slide a drawer target moves on; None for doors and knobs."""
    joint = view.articulation_joints(target)[0]
    return view.joint(joint) if _is_slide(view, joint) else None


def _pulled_out(view: SimView, target: str, travel: Callable[[dict], float]) -> np.ndarray | None:
    """Corners of a drawer's collision boxes (8 per box) pulled out by `travel(joint info)` metres from
    where they are now (None for doors and knobs)."""
    info = _drawer_joint(view, target)
    if info is None:
        return None
    _, opening, _ = _slide(view, target)
    return view.geom_points(_fixture(view, target), body=info["body"]) + opening * travel(info)


def opened_footprint(view: SimView, target: str) -> tuple[np.ndarray, np.ndarray] | None:
    """The xy box a drawer covers when pulled out to its end stop (None for doors and knobs)."""
    pts = _pulled_out(view, target, lambda info: _short_of_stop(view, target, info))
    return None if pts is None else (pts[:, :2].min(axis=0), pts[:, :2].max(axis=0))


# m a drawer's pull overshoots where LIBERO starts calling it open: the pull stops once it does
PULL_OVERSHOOT = 0.01
# The hand may come down this far (m) into what is around a grasp (a rim grasp next to a drawer): a
# bowl whose every grasp under an opened drawer brings the hand closer is moved clear before opening.
REACH_TOLERANCE = 0.012


def opened_points(view: SimView, target: str) -> np.ndarray | None:
    """Points through a drawer's volume where the pull will leave it: just past where LIBERO calls it
    open (None for doors and knobs)."""
    open_at = view.open_position(_fixture(view, target))
    corners = _pulled_out(view, target, lambda info: abs(open_at - info["qpos"]) + PULL_OVERSHOOT)
    return None if corners is None else fill_boxes(corners.reshape(-1, 8, 3))


def under_opened(view: SimView, target: str, obj: str) -> bool:
    """Would the opened drawer hang over `obj` so that no top-down grasp reaches it any more? Picked by
    what still sticks out (a bowl's rim) it is lifted and carried out sideways (`skills.pick`);
    otherwise it must be moved clear before the drawer is opened. Only the drawer counts: an object
    that its neighbours already crowd is not moved for them."""
    drawer = opened_points(view, target)
    if drawer is None:
        return False
    before, after = choose_grasp(view, obj), choose_grasp(view, obj, also_avoid=drawer)
    if before is None or after is None:
        return before is not None
    return after.clearance < min(-REACH_TOLERANCE, before.clearance)


def clear_spot(view: SimView, target: str, obj: str, margin: float = 0.04) -> np.ndarray:
    """Where to set `obj` down so that it stands clear of the opened drawer: straight out along the
    opening direction, just past the drawer's front edge."""
    _, opening, _ = _slide(view, target)
    lo, hi = opened_footprint(view, target)
    corners = np.array([[x, y] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])])
    front = float((corners @ opening[:2]).max())
    pts = view.geom_points(obj)[:, :2]
    centre = view.position(obj)[:2]
    behind = float(((pts - centre) @ opening[:2]).min())  # the object's extent back towards the drawer (< 0)
    return centre + opening[:2] * (front - centre @ opening[:2] - behind + margin)


FULLY_OUT = 0.005  # m short of its end stop at which a drawer counts as pulled all the way out
HOOK_DEPTH = 0.025  # m above the drawer's floor where the fingertips hook behind its front panel
HOOK_INSIDE = 0.015  # m behind the front panel's inner face (the drawer region's near edge)


def pulled_short(view: SimView, target: str) -> float:
    """How far (m) a drawer stands short of its end stop; 0 for doors and knobs."""
    info = _drawer_joint(view, target)
    return 0.0 if info is None else _short_of_stop(view, target, info)


def _short_of_stop(view: SimView, target: str, info: dict) -> float:
    """`pulled_short` from the drawer's slide joint info (`SimView.joint`)."""
    lo, hi = info["range"]
    return abs((hi if view.opening_sign(_fixture(view, target)) > 0 else lo) - info["qpos"])


def pull_out(ctx: SkillContext, target: str) -> Actions:
    """Pull a partly open drawer out to its end stop, the closed fingertips hooked behind its front panel
    from above: about 70 steps, against ~160 for a pull by the handle (the hand turned level and back).
    libero_10/3 starts with its bottom drawer 1.4 cm short of the stop, and the 10.7 cm bowl fits
    between the drawer's front panel and the handle of the drawer above only with that 1.4 cm."""
    view = ctx.view
    _, opening, _ = _slide(view, target)
    region = view.region(target)
    axes, half = region.footprint()
    near_edge = float(np.abs(axes.T @ opening[:2]) @ half)
    hook = region.position.copy()
    hook[:2] += opening[:2] * (near_edge - HOOK_INSIDE)
    hook[2] = region.bottom + HOOK_DEPTH
    rot = hand_down(view, float(np.arctan2(opening[1], opening[0])), at=hook, shortest=True)  # fingers across the pull
    yield from ctx.goto(
        np.array([*hook[:2], max(view.eef_position()[2], hook[2] + 0.10)]),
        rot,
        CLOSE,
        tol=0.02,
        rot_tol=0.15,
        max_steps=100,
    )
    yield from ctx.goto(hook, rot, CLOSE, tol=0.008, max_steps=60, speed=0.6)
    out = lambda: pulled_short(view, target) < FULLY_OUT / 2  # noqa: E731
    yield from ctx.goto(
        hook + opening * (pulled_short(view, target) + 0.01), rot, CLOSE, tol=0.01, max_steps=30, until=out
    )
    yield from ctx.goto(view.eef_position() + np.array([0.0, 0.0, 0.10]), rot, CLOSE, tol=0.02, max_steps=30)
    return out()


def doorway(view: SimView, target: str) -> tuple[np.ndarray, float] | None:
    """For a region under a roof behind a hinged door (a microwave's heating region): the horizontal
    direction its doorway faces and where the doorway's plane lies along it (the closed door's inner
    face). None for regions open from above, such as a stove's burner, whose knob is a hinge too.
    Objects go in through the doorway: a top-down carry sets them on the roof."""
    joints = view.articulation_joints(target) if target in view.regions else ()
    if (
        not joints
        or view.region_joints(target)
        or _is_slide(view, joints[0])
        or floor_and_roof(view, target)[1] is None
    ):
        return None
    info = view.joint(joints[0])
    entity = _fixture(view, target)
    closed = float(info["range"][1] if view.opening_sign(entity) < 0 else info["range"][0])
    turn = rot_axis(info["axis"], closed - info["qpos"])
    door = (view.geom_points(entity, body=info["body"]) - info["anchor"]) @ turn.T + info["anchor"]
    flat = door[:, :2] - door[:, :2].mean(axis=0)
    _, vectors = np.linalg.eigh(flat.T @ flat)
    # The shut door's thinnest horizontal direction is its normal; a handle and frame skew it by a few
    # degrees, so it is taken as the fixture's own horizontal axis closest to it.
    axes = view.rotation(entity)[:, :2].T
    facing = np.array([*(axes[np.argmax(np.abs(axes @ np.array([*vectors[:, 0], 0.0])))][:2]), 0.0])
    if facing @ (door.mean(axis=0) - view.region(target).position) < 0:
        facing = -facing
    return facing, float((door @ facing).min())


def open_(ctx: SkillContext, target: str) -> Actions:
    """Open a drawer (pull its handle) or a hinged door; True once LIBERO calls it open."""
    view = ctx.view
    joint = view.articulation_joints(target)[0]
    if _is_slide(view, joint):
        return (yield from _pull_drawer(ctx, target))
    return (yield from _swing_door(ctx, target, opening=True))


def close(ctx: SkillContext, target: str) -> Actions:
    """Close a drawer (push its front) or a hinged door."""
    view = ctx.view
    joint = view.articulation_joints(target)[0]
    if _is_slide(view, joint):
        return (yield from _push_drawer(ctx, target))
    return (yield from _swing_door(ctx, target, opening=False))


def _is_slide(view: SimView, joint: str) -> bool:
    return view.joint_type(joint) == "slide"


# The hand housing spans ~20 cm along the fingers' closing direction: closing vertically on a handle, its
# lower edge sits ~10 cm below the handle and scrapes whatever stands in front of the drawer (a plate,
# a bowl). Rolled this far (46 deg) from vertical, it sits ~3 cm higher and the fingers still pinch the bar.
HANDLE_ROLL = 0.8
# Height above the handle at which the hand travels to the drawer before coming down in front of it.
APPROACH_CLEARANCE = 0.12
APPROACH_SPEED = 0.8  # of the servo's top speed, for the last 10 cm to the handle
PULL_SPEED = 1.0  # of the servo's top speed, for the pull
GRASP_DEPTH = 0.004  # m behind the handle bar's front face where the grip point closes on it


def _pull_drawer(ctx: SkillContext, target: str) -> Actions:
    view = ctx.view
    _, opening, handle = _slide(view, target)
    rot = _handle_grip(view, opening)
    standoff = handle + opening * 0.10
    travel = max(view.eef_position()[2], handle[2] + APPROACH_CLEARANCE)
    yield from ctx.goto(np.array([*standoff[:2], travel]), rot, OPEN, tol=0.02, rot_tol=0.2, max_steps=100)
    yield from ctx.goto(standoff, rot, OPEN, tol=0.02, max_steps=120)
    yield from ctx.goto(handle - opening * GRASP_DEPTH, rot, OPEN, tol=0.006, max_steps=60, speed=APPROACH_SPEED)
    yield from ctx.hold(CLOSE, 10, rot)
    is_open = lambda: view.predicate(("open", target))  # noqa: E731
    for _ in range(3):
        goal = view.eef_position() + opening * 0.20
        yield from ctx.goto(goal, rot, CLOSE, tol=0.015, max_steps=80, speed=PULL_SPEED, until=is_open)
        if is_open():
            break
    yield from ctx.release(rot)
    yield from _point_down(ctx, opening)
    return view.predicate(("open", target))


def _handle_grip(view: SimView, opening: np.ndarray) -> np.ndarray:
    """The hand facing the handle, rolled `HANDLE_ROLL` from vertical, or the same grip half a turn
    about the pointing axis (a parallel gripper is symmetric, and the housing sits where it did),
    whichever the hand turns to the shorter way from where it points now: from pointing down one takes
    ~1.7 rad of turn, the other ~2.6, ~30 steps of OSC turning each way. The wrist (the last joint)
    holds the half-turned grip at ~2.4 rad in libero_goal's kitchen, whose cabinet faces the robot, and
    the other one at ~-0.8; with a cabinet turned ~0.5 rad the half-turned grip, still the shorter
    turn, would reach the joint's 2.9 rad stop, so a scene with one needs the wrist checked here."""
    current = view.eef_rotation()
    grips = [_hand_facing(-opening, roll) for roll in (HANDLE_ROLL, HANDLE_ROLL + np.pi)]
    return min(grips, key=lambda grip: float(np.linalg.norm(rotation_error(grip, current))))


RETREAT = 0.08  # m the hand backs off towards the robot while it turns back to pointing down
LET_GO = 0.08  # m the opened hand backs off the handle along the drawer's opening direction meanwhile
TURN_TOL = 0.15  # rad left of the turn back to pointing down when the next skill takes over


def _point_down(ctx: SkillContext, opening: np.ndarray) -> Actions:
    """Tilt the level hand back to pointing down while it backs off the handle, rises and backs off
    towards the robot, in one move: done on the way to the next pick, the quarter turn drags the hand
    off course and into the cabinet; done at full reach (a drawer pulled out far), it stretches the
    elbow straight, where OSC cannot bend it back. The hand is only tilted down, its wrist kept as the
    grip left it: a turn about the vertical is the next pick's, which knows its grasp (`hand_down`).
    The last `TURN_TOL` of the tilt is left to that pick's first move, which turns the hand while it
    travels."""
    view = ctx.view
    toward_base = view.robot_base_position()[:2] - view.eef_position()[:2]
    back = opening * LET_GO + np.array([*(RETREAT * toward_base / np.linalg.norm(toward_base)), 0.06])
    yield from ctx.goto(
        view.eef_position() + back, pitched_down(view.eef_rotation()), OPEN, tol=0.03, rot_tol=TURN_TOL, max_steps=60
    )


# Drawers are pushed shut with the closed fingertips on the front panel, the hand pointing down and
# pitched this far (rad) towards the cabinet: the hand and arm stay above and in front of the drawer,
# clear of whatever stands in front of the cabinet (a wine rack behind the robot's reach), where a
# horizontal hand needs its whole forearm's length free in front of the handle.
PUSH_PITCH = 0.5
PUSH_STANDOFF = 0.04  # m in front of the handle where the fingertips come down


def _push_drawer(ctx: SkillContext, target: str) -> Actions:
    view = ctx.view
    _, opening, handle = _slide(view, target)
    push = -opening
    yaw = float(np.arctan2(push[1], push[0]))  # fingers side by side across the push
    down = hand_down(view, yaw, at=handle, shortest=True)
    rot = rot_axis(np.cross(push, [0.0, 0.0, 1.0]), PUSH_PITCH) @ down
    start = handle + opening * PUSH_STANDOFF
    yield from ctx.goto(
        np.array([*start[:2], max(view.eef_position()[2], handle[2] + 0.10)]),
        rot,
        CLOSE,
        tol=0.02,
        rot_tol=0.2,
        max_steps=100,
    )
    yield from ctx.goto(start, rot, CLOSE, tol=0.01, max_steps=80)
    is_closed = lambda: view.predicate(("close", target))  # noqa: E731
    for _ in range(3):
        goal = view.eef_position() + push * 0.25
        yield from ctx.goto(goal, rot, CLOSE, tol=0.02, max_steps=80, speed=0.6, until=is_closed)
        if is_closed():
            break
    yield from ctx.goto(
        view.eef_position() + opening * 0.05 + np.array([0, 0, 0.08]), down, OPEN, tol=0.02, max_steps=30
    )
    return view.predicate(("close", target))


DOOR_STEP = 0.25  # rad of door swing per waypoint along the free edge's arc
DOOR_BEHIND = 0.5  # rad behind the door's edge where the hand comes down: beyond the door's thickness


def _swing_door(ctx: SkillContext, target: str, opening: bool) -> Actions:
    """Hinged doors (the microwave): push the door's free edge along its arc with the closed hand."""
    view = ctx.view
    joint = view.articulation_joints(target)[0]
    info = view.joint(joint)
    entity = _fixture(view, target)
    pts = view.geom_points(entity, body=info["body"])
    anchor, axis = info["anchor"], info["axis"]
    radial = pts - anchor
    radial -= np.outer(radial @ axis, axis)
    edge = pts[np.argmax(np.linalg.norm(radial, axis=1))]
    arm = edge - anchor
    arm -= (arm @ axis) * axis
    sign = view.opening_sign(entity) * (1.0 if opening else -1.0)
    rot = grasp_rotation(0.0)
    query = "open" if opening else "close"

    def along_arc(angle: float) -> np.ndarray:
        point = anchor + rot_axis(axis, sign * angle) @ arm * 0.85
        point[2] = edge[2] if abs(axis[2]) > 0.9 else point[2]
        return point

    # Come down behind the door's edge from above, clear of the door and of what the hand just left.
    behind = along_arc(-DOOR_BEHIND)
    over = max(view.eef_position()[2], pts[:, 2].max() + 0.05)
    yield from ctx.goto(np.array([*view.eef_position()[:2], over]), rot, CLOSE, tol=0.03, max_steps=40)
    yield from ctx.goto(np.array([*behind[:2], over]), rot, CLOSE, tol=0.03, max_steps=60)
    yield from ctx.goto(behind, rot, CLOSE, tol=0.02, max_steps=40)
    for step in range(1, int(np.ptp(info["range"]) / DOOR_STEP) + 2):  # as far as the hinge turns
        yield from ctx.goto(along_arc(DOOR_STEP * step), rot, CLOSE, tol=0.02, max_steps=40, speed=0.6)
        if view.predicate((query, target)):
            break
    yield from ctx.goto(view.eef_position() + np.array([0, 0, 0.08]), rot, OPEN, tol=0.03, max_steps=30)
    return view.predicate((query, target))


KNOB_STEP, KNOB_STEPS = 0.15, 7  # rad per wrist increment, and at most this many increments


def turn(ctx: SkillContext, target: str, on: bool) -> Actions:
    """Turn a stove knob on or off: grasp its grip bar from above and rotate about the hinge."""
    view = ctx.view
    joint = view.articulation_joints(target)[0]
    info = view.joint(joint)
    pts = view.geom_points(target, body=info["body"])
    top = pts[pts[:, 2] >= pts[:, 2].max() - 0.03]
    centre = top.mean(axis=0)
    extent = top.max(axis=0) - top.min(axis=0)
    # Fingers close across the bar's thin horizontal side.
    yaw = 0.0 if extent[1] <= extent[0] else np.pi / 2
    grip = np.array([centre[0], centre[1], top[:, 2].max() - 0.015])
    sign = (1.0 if on else -1.0) * np.sign(info["axis"][2] or 1.0)
    rot = hand_down(view, yaw, at=grip, then=sign * KNOB_STEP * KNOB_STEPS)
    yield from ctx.goto(np.array([*grip[:2], grip[2] + 0.10]), rot, OPEN, tol=0.015, max_steps=150)
    yield from ctx.goto(grip, rot, OPEN, tol=0.006, max_steps=60, speed=0.5)
    yield from ctx.hold(CLOSE, 10, rot)
    query = "turnon" if on else "turnoff"
    anchor = info["anchor"]
    for k in range(1, KNOB_STEPS + 1):
        angle = sign * KNOB_STEP * k
        pos = anchor + rot_z(angle) @ (grip - anchor)
        yield from ctx.goto(pos, rot_z(angle) @ rot, CLOSE, tol=0.01, rot_tol=0.05, max_steps=25, speed=0.5)
        if view.predicate((query, target)) and k >= 5:
            break
    yield from ctx.release()
    yield from ctx.goto(view.eef_position() + np.array([0, 0, 0.08]), view.eef_rotation(), OPEN, tol=0.02, max_steps=30)
    return view.predicate((query, target))
