"""Grasp and placement geometry from the simulator's collision shapes.

A general grasp chooser instead of per-task trajectories: for every candidate yaw it checks that the
object fits between the fingers (the Panda opens ~8 cm); objects too wide for that are held by a slender
part the fingers can close around without touching the rest of the object (a moka pot's handle) or, if
they are open at the top (bowls, plates), by the rim, radially. It then keeps the candidate whose hand
footprint (~21 cm along the closing direction) stays clearest of the neighbours, since the hand hitting
neighbours is the main failure.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from base_suites.experts.control import finger_axis, rot_axis
from base_suites.sim_view import SimView

MAX_WIDTH = 0.072  # widest object the fingers close around reliably
HAND_HALF_LENGTH = 0.105  # hand extent along the closing direction, each side of the centre
HAND_HALF_WIDTH = 0.035
PART_MAX_WIDTH = 0.03  # widest part (handle) pinched on its own
FINGER_HALF_WIDTH = 0.009  # finger pad extent across the closing direction
FINGER_THICKNESS = 0.022  # room a finger needs beside the pinched part
OPEN_HALF_SPAN = 0.04  # the open fingers come down this far out from the grip centre
YAWS = np.deg2rad(np.arange(-90, 90, 15))
REACH_LIMIT = 0.72  # m (xy) from the robot base: beyond it, a hand low over the table straightens the elbow
STRETCH_PENALTY = 10.0  # per metre beyond REACH_LIMIT: outweighs up to 4 cm of clearance per 4 cm of stretch


@dataclass(frozen=True)
class Grasp:
    position: np.ndarray
    yaw: float
    clearance: float
    rim: bool


@dataclass(frozen=True)
class Shape:
    """Axis-aligned world extents of an entity's collision geoms."""

    low: np.ndarray
    high: np.ndarray

    @property
    def centre(self) -> np.ndarray:
        return (self.low + self.high) / 2

    @property
    def top(self) -> float:
        return float(self.high[2])

    @property
    def bottom(self) -> float:
        return float(self.low[2])

    @property
    def height(self) -> float:
        return float(self.high[2] - self.low[2])


def shape_of(view: SimView, entity: str) -> Shape:
    pts = view.geom_points(entity)
    return Shape(pts.min(axis=0), pts.max(axis=0))


def standing_points(view: SimView, entity: str) -> np.ndarray:
    """Box corners of `entity` (8 per box) as it will stand once set down: turned about its origin so
    that the local axis nearest world up points straight up. A bowl hangs ~15 deg tilted from a rim
    grasp and lands flat, and its tilted footprint reaches ~1 cm further to one side, which is all the
    room a bowl has in a drawer; a can lying on its side stays lying."""
    pts, origin, rot = view.geom_points(entity), view.position(entity), view.rotation(entity)
    nearest = int(np.argmax(np.abs(rot[2])))
    up = rot[:, nearest] * np.sign(rot[2, nearest])
    axis = np.cross(up, [0.0, 0.0, 1.0])
    sin = float(np.linalg.norm(axis))
    if sin < 1e-9:
        return pts
    return (pts - origin) @ rot_axis(axis / sin, float(np.arctan2(sin, up[2]))).T + origin


def _extent(points: np.ndarray, direction: np.ndarray) -> float:
    proj = points[:, :2] @ direction[:2]
    return float(proj.max() - proj.min())


def _hand_clearance(centre: np.ndarray, yaw: float, z: float, obstacles: np.ndarray) -> float:
    """Smallest xy distance from obstacle points (above the fingertips) to the hand's footprint."""
    relevant = obstacles[obstacles[:, 2] > z - 0.01] if len(obstacles) else obstacles
    if len(relevant) == 0:
        return 1.0
    return float(np.min(_hand_footprint_distance(centre, yaw, relevant)))


def _hand_footprint_distance(centre: np.ndarray, yaw: float, points: np.ndarray) -> np.ndarray:
    """Signed xy distance of each point from the hand's footprint around `centre` (negative inside)."""
    along = finger_axis(yaw)[:2]
    across = np.array([-along[1], along[0]])
    rel = points[:, :2] - centre[:2]
    a = np.abs(rel @ along) - HAND_HALF_LENGTH
    c = np.abs(rel @ across) - HAND_HALF_WIDTH
    outside = np.sqrt(np.clip(a, 0, None) ** 2 + np.clip(c, 0, None) ** 2)
    inside = np.minimum(np.maximum(a, c), 0)
    return np.where((a > 0) | (c > 0), outside, inside)


def _obstacle_points(view: SimView, entity: str, filled: bool = False) -> np.ndarray:
    """Collision-box corners of everything but `entity` and the robot; `filled`: points through their
    volumes, for checks against large boxes (an object under a drawer's bottom panel is near none of
    its corners)."""
    others = [view.geom_points(e) for e in view.objects + view.fixtures if e != entity]
    if filled:
        others = [fill_boxes(p.reshape(-1, 8, 3)) for p in others]
    return np.concatenate(others) if others else np.zeros((0, 3))


def _covers_centre(parts: np.ndarray, shape: Shape) -> bool:
    """Whether some part above mid-height spans the object's centre (a lid or body, not an open bowl)."""
    centre, mid = shape.centre[:2], shape.bottom + 0.5 * shape.height
    for pts in parts:
        low, high = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
        if pts[:, 2].max() > mid and np.all(low <= centre) and np.all(centre <= high):
            return True
    return False


# 9 x 9 x 3 points per box: ~1 cm apart on a 9 cm pot body, finer than a finger's band.
_LATTICE = np.array(
    [[a, b, c] for a in np.linspace(-1, 1, 9) for b in np.linspace(-1, 1, 9) for c in np.linspace(-1, 1, 3)]
)


def fill_boxes(parts: np.ndarray, spacing: float | None = None) -> np.ndarray:
    """Points through the volume of each box given by its 8 corners (SimView order: x, y, z nested),
    so checks see faces between corners: a fixed 9 x 9 x 3 lattice per box, or with `spacing` (m) at
    most that far apart along every edge (a drawer's 22 cm front panel, whose long edge may be the one
    the fixed lattice samples thrice, for a placement that has millimetres to spare)."""
    origin = parts[:, 0]
    ex, ey, ez = (parts[:, 4] - origin) / 2, (parts[:, 2] - origin) / 2, (parts[:, 1] - origin) / 2
    centre = origin + ex + ey + ez
    if spacing is None:
        filled = (
            centre[:, None]
            + _LATTICE[None, :, :1] * ex[:, None]
            + _LATTICE[None, :, 1:2] * ey[:, None]
            + _LATTICE[None, :, 2:] * ez[:, None]
        )
        return filled.reshape(-1, 3)
    boxes = []
    for c, *edges in zip(centre, ex, ey, ez):
        steps = [np.linspace(-1, 1, max(2, int(np.ceil(2 * np.linalg.norm(e) / spacing)) + 1)) for e in edges]
        grid = np.stack(np.meshgrid(*steps, indexing="ij"), axis=-1).reshape(-1, 3)
        boxes.append(c + grid @ np.array(edges))
    return np.concatenate(boxes) if boxes else np.zeros((0, 3))


def _part_pinches(parts: np.ndarray) -> list[Grasp]:
    """Pinches of one slender part (a handle): where the fingers come down open and close across it,
    they find no other part of the object above the fingertips."""
    everything = fill_boxes(parts)
    grasps = []
    for pts in parts:
        centre = (pts.min(axis=0) + pts.max(axis=0)) / 2
        top, bottom = float(pts[:, 2].max()), float(pts[:, 2].min())
        if top - bottom < 0.01:
            continue
        z = max(bottom + 0.008, top - 0.015)
        above = everything[everything[:, 2] > z - 0.005]
        best: tuple[float, float] | None = None  # (width, yaw) of the narrowest closure that fits
        for yaw in YAWS:
            axis = finger_axis(yaw)
            width = _extent(pts, axis)
            if width > PART_MAX_WIDTH or (best is not None and width >= best[0]):
                continue
            rel = above[:, :2] - centre[:2]
            along = np.abs(rel @ axis[:2])
            across = np.abs(rel @ np.array([-axis[1], axis[0]]))
            # Where the fingers pass: from their open position down to closed on the part.
            in_finger = (
                (across < FINGER_HALF_WIDTH)
                & (along > width / 2 + 0.003)
                & (along < OPEN_HALF_SPAN + FINGER_THICKNESS / 2)
            )
            if not in_finger.any():
                best = (width, float(yaw))
        if best is not None:
            grasps.append(Grasp(np.array([centre[0], centre[1], z]), best[1], 0.0, rim=False))
    return grasps


RIM_INSET, RIM_DEPTH = 0.012, 0.018  # fingertips this far inside a rim's outer edge and below its top
LEVEL_RADIAL = 0.26  # sin 15 deg: how far from level the wall's outward direction may be at a rim grasp


def _rim_grasps(view: SimView, entity: str, yaw: float) -> list[Grasp]:
    """Pinches across the wall of a wide open object (a bowl) at its rim, the fingers closing along
    `yaw`'s axis, found in the object's own frame. The fingers must meet the wall where it stands upright
    across the closing direction: all round an upright bowl, but on a tipped one (libero_spatial/5's
    bowl slides off its ramekin and rests 51 deg tilted) only on the two sides level with the axis it
    tipped about; elsewhere the wall leans across the fingers and slips out as they close."""
    rotation, origin = view.rotation(entity), view.position(entity)
    local = (view.geom_points(entity) - origin) @ rotation
    axis = finger_axis(yaw)
    radial = rotation.T @ np.array([axis[0], axis[1], 0.0])
    if abs(radial[2]) > LEVEL_RADIAL:
        return []
    outward = radial[:2] / np.linalg.norm(radial[:2])
    reach = local[:, :2] @ outward
    centre = local[:, :2].mean(axis=0)
    centre += (
        (reach.max() + reach.min()) / 2 - centre @ outward
    ) * outward  # midway across the wall along the closing axis
    top = local[:, 2].max()
    grasps = []
    for side in (-1.0, 1.0):
        point = origin + rotation @ np.array([*(centre + side * (np.ptp(reach) / 2 - RIM_INSET) * outward), top])
        grasps.append(Grasp(np.array([point[0], point[1], point[2] - RIM_DEPTH]), yaw, 0.0, rim=True))
    return grasps


def choose_grasp(
    view: SimView,
    entity: str,
    prefer_yaw: float = 0.0,
    destination: np.ndarray | None = None,
    also_avoid: np.ndarray | None = None,
) -> Grasp | None:
    """The clearest feasible top-down grasp of an object (pinch across a narrow side, a slender part,
    or the rim of an open object); None if none fits (flat plates are pushed instead). With the xy
    `destination` the object is to be carried to, a rim grasp that would put the hand beyond the arm's
    comfortable reach there is avoided: at full stretch the elbow locks straight and OSC stalls.
    `also_avoid`: points of something not yet where it will be (a drawer once pulled open)."""
    points = view.geom_points(entity)
    parts = points.reshape(-1, 8, 3)
    shape = Shape(points.min(axis=0), points.max(axis=0))
    obstacles = _obstacle_points(view, entity)
    if also_avoid is not None:
        obstacles = np.concatenate([obstacles, also_avoid])
    centre = shape.centre
    pinch_z = _pinch_height(shape)
    pinches, rims = [], []
    open_top = not _covers_centre(parts, shape)
    for yaw in YAWS:
        axis = finger_axis(yaw)
        width = _extent(points, axis)
        if width <= MAX_WIDTH:
            pinches.append(Grasp(np.array([centre[0], centre[1], pinch_z]), float(yaw), 0.0, rim=False))
        elif shape.height > 0.03:
            rims += _rim_grasps(view, entity, float(yaw))

    base = view.robot_base_position()[:2]
    goal = None if destination is None else np.asarray(destination, dtype=float)[:2]

    def score(cand: Grasp) -> tuple[float, Grasp]:
        clearance = _hand_clearance(cand.position, cand.yaw, cand.position[2], obstacles)
        # Clearance first (capped: beyond 4 cm it no longer matters), then little wrist rotation, then
        # rim points on the robot's side: the object then hangs away from the robot and every later
        # move of the hand stays further inside the arm's reach.
        reach = float(np.linalg.norm(cand.position[:2] - base)) if cand.rim else 0.0
        stretch = (
            0.0
            if goal is None
            else max(0.0, float(np.linalg.norm(goal + cand.position[:2] - centre[:2] - base)) - REACH_LIMIT)
        )
        value = min(clearance, 0.04) * 10 - 0.02 * abs(cand.yaw - prefer_yaw) - 1.0 * reach - STRETCH_PENALTY * stretch
        return value, Grasp(cand.position, cand.yaw, clearance, cand.rim)

    scored = [score(c) for c in pinches]
    if not scored or max(v for v, _ in scored) <= 0.05:  # no pinch clear of the neighbours
        scored += [score(c) for c in rims] if open_top else [score(c) for c in _part_pinches(parts)]
    if not scored:  # nothing fits (a can lying on its side): rims are the best bet, if any
        scored = [score(c) for c in rims]
    return max(scored, key=lambda vs: vs[0])[1] if scored else None


def handle_pinch(view: SimView, entity: str) -> Grasp | None:
    """The pinch of the slender part standing farthest out from the object's origin (a mug's handle):
    held there, the object leads with its body and the hand trails behind it. None without one."""
    parts = view.geom_points(entity).reshape(-1, 8, 3)
    origin = view.position(entity)[:2]
    pinches = _part_pinches(parts)
    return max(pinches, key=lambda g: float(np.linalg.norm(g.position[:2] - origin)), default=None)


def narrowest_pinch(view: SimView, entity: str) -> Grasp:
    """The last resort when `choose_grasp` finds nothing: close across the object's narrowest side."""
    points = view.geom_points(entity)
    shape = Shape(points.min(axis=0), points.max(axis=0))
    yaw = min(YAWS, key=lambda y: _extent(points, finger_axis(y)))
    return Grasp(np.array([*shape.centre[:2], _pinch_height(shape)]), float(yaw), 0.0, rim=False)


def _pinch_height(shape: Shape) -> float:
    """Fingertips 3.5 cm below the top (half way down short objects), never at the table."""
    return max(shape.bottom + 0.012, shape.top - min(0.035, shape.height * 0.5))


def carry_height(
    view: SimView,
    held: str,
    goal_xy: np.ndarray,
    margin: float = 0.05,
    clearance: float = 0.06,
    ahead_only: bool = False,
) -> float:
    """Height of the grip point that keeps the held object's bottom `margin` above everything in the
    corridor between where it is and where it goes (not above the whole scene: tall cabinets elsewhere
    would force needlessly high, slow carries). `ahead_only`: what stands behind the object's start
    does not count, for a carry straight away from what it stood against (a bowl moved out from in
    front of a cabinet need not be lifted over the cabinet's drawers)."""
    held_shape = shape_of(view, held)
    grip_to_bottom = view.eef_position()[2] - held_shape.bottom
    start = held_shape.centre[:2]
    corridor = 0.5 * float(np.max(held_shape.high[:2] - held_shape.low[:2])) + clearance
    seg = np.asarray(goal_xy, dtype=float)[:2] - start
    length = max(np.linalg.norm(seg), 1e-6)
    tops = [view.table_height]
    for entity in view.objects + view.fixtures:
        if entity == held:
            continue
        pts = view.geom_points(entity)
        rel = pts[:, :2] - start
        along = rel @ seg / length**2
        t = np.clip(along, 0, 1)
        dist = np.linalg.norm(rel - t[:, None] * seg, axis=1)
        near = pts[(dist < corridor) & ((along > 0) | (not ahead_only))]
        if len(near):
            tops.append(float(near[:, 2].max()))
    return max(tops) + margin + grip_to_bottom


def floor_and_roof(view: SimView, target: str) -> tuple[float | None, float | None]:
    """Heights of what the region's fixture has right under and right over the region (None where it
    has nothing: a stove's burner region has no roof)."""
    region = view.region(target)
    axes, half = region.footprint()
    pts = view.geom_points(region.parent)
    local = np.abs((pts[:, :2] - region.position[:2]) @ axes)
    over = pts[np.all(local <= half, axis=1)] if half is not None else pts
    below, above = over[over[:, 2] < region.position[2]], over[over[:, 2] > region.position[2]]
    return (float(below[:, 2].max()) if len(below) else None), (float(above[:, 2].min()) if len(above) else None)


def push_yaw(view: SimView, entity: str, press: np.ndarray, direction: np.ndarray, z: float) -> float:
    """Grasp yaw for pushing `entity` in `direction` with the fingertips at `press`: the hand's long side
    across the push (two fingers wide), unless it lies along the push clearer of the neighbours (the
    ~21 cm hand across a plate's push sweeps over the bowl beside it)."""
    across = float(np.arctan2(direction[1], direction[0]))
    obstacles = _obstacle_points(view, entity)
    return max((across, across + np.pi / 2), key=lambda yaw: _hand_clearance(press, yaw, z, obstacles))


SLIDE_GRID = 0.01  # m between the cells of the sliding planner's grid
SLIDE_MARGIN = 0.15  # m the grid reaches beyond the start and the goal
SLIDE_GAP = 0.02  # m a slid object's rim keeps from anything standing on the table
BLOCKED_COST = 30.0  # a metre through a cell without that gap costs as much as this many metres clear


def slide_path(view: SimView, entity: str, goal_xy: np.ndarray) -> list[np.ndarray]:
    """Waypoints (xy, ending at `goal_xy`) along which to slide `entity` over the table so that its
    footprint keeps `SLIDE_GAP` from everything else standing there: a plate pushed straight to the front
    of libero_goal's stove runs into the cream cheese lying beside that spot, and shoves it along.
    The shortest such path on a 1 cm grid (cells short of the gap are not forbidden but cost
    `BLOCKED_COST` times their length, since the object may start or end close to a neighbour), then
    shortened to the fewest straight legs that stay as clear."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra
    from scipy.spatial import cKDTree

    start, goal = view.position(entity)[:2], np.asarray(goal_xy, dtype=float)[:2]
    radius = float(np.max(np.linalg.norm(view.geom_points(entity)[:, :2] - start, axis=1)))
    shape = shape_of(view, entity)
    points = _obstacle_points(view, entity, filled=True)
    points = points[(points[:, 2] > view.table_height + 0.003) & (points[:, 2] < shape.top + 0.01)][:, :2]
    if len(points) == 0:
        return [goal]
    tree = cKDTree(points)
    low = np.minimum(start, goal) - SLIDE_MARGIN
    nx, ny = np.ceil((np.maximum(start, goal) + SLIDE_MARGIN - low) / SLIDE_GRID).astype(int) + 1
    cells = low + SLIDE_GRID * np.stack(np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij"), axis=-1).reshape(
        -1, 2
    )
    weight = np.where(tree.query(cells)[0] > radius + SLIDE_GAP, 1.0, BLOCKED_COST)
    rows, cols, costs = [], [], []
    index = np.arange(nx * ny).reshape(nx, ny)
    for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
        a = index[max(0, -dx) : nx - max(0, dx), max(0, -dy) : ny - max(0, dy)].ravel()
        b = index[max(0, dx) : nx - max(0, -dx), max(0, dy) : ny - max(0, -dy)].ravel()
        step = SLIDE_GRID * np.hypot(dx, dy) * (weight[a] + weight[b]) / 2
        rows += [a, b]
        cols += [b, a]
        costs += [step, step]
    graph = csr_matrix((np.concatenate(costs), (np.concatenate(rows), np.concatenate(cols))), shape=(nx * ny, nx * ny))
    source = int(np.argmin(np.linalg.norm(cells - start, axis=1)))
    sink = int(np.argmin(np.linalg.norm(cells - goal, axis=1)))
    _, previous = dijkstra(graph, indices=source, return_predecessors=True)
    chain = [sink]
    while chain[-1] != source and previous[chain[-1]] >= 0:
        chain.append(int(previous[chain[-1]]))
    path = [start] + [cells[i] for i in reversed(chain[1:-1])] + [goal]
    return _straighten(path, tree, radius + SLIDE_GAP)


def _straighten(path: list[np.ndarray], tree, needed: float) -> list[np.ndarray]:
    """The grid path as few straight legs: from each corner, the farthest later point reached by a
    straight leg at least as clear as the grid path between them (or clear by `needed`)."""
    clear = tree.query(np.array(path))[0]
    legs, i = [], 0
    while i < len(path) - 1:
        j = len(path) - 1
        while j > i + 1 and _leg_clearance(tree, path[i], path[j]) < min(needed, clear[i : j + 1].min()) - 1e-9:
            j -= 1
        legs.append(path[j])
        i = j
    return legs


def _leg_clearance(tree, a: np.ndarray, b: np.ndarray) -> float:
    """Smallest distance from the straight leg a -> b (sampled every grid cell) to an obstacle point."""
    n = max(2, int(np.ceil(np.linalg.norm(b - a) / SLIDE_GRID)) + 1)
    return float(tree.query(np.linspace(a, b, n))[0].min())


# A held object under an overhang (a bowl standing where an opened drawer now hangs over it, picked by
# the part of its rim that sticks out) can rise only so far, and must be carried out sideways first.
HOUSING_ABOVE_GRIP = 0.045  # m from the grip point up to the hand housing's lower face: the fingers' length
OVERHANG_GAP = 0.015  # m a held object and the hand keep from what hangs over them on the way out
WAY_OUT_STEP, WAY_OUT_REACH = 0.01, 0.20  # m: the shifts tried, every 16th of a turn
WAY_OUT_DIRECTIONS = np.array([[np.cos(a), np.sin(a)] for a in np.linspace(0, 2 * np.pi, 16, endpoint=False)])


def _around_held(
    view: SimView, held: str
) -> tuple[np.ndarray, Callable[[np.ndarray], np.ndarray], np.ndarray, np.ndarray]:
    """The held object's filled footprint (xy) and the test of which xy points lie over it; the filled
    points, above its top, of whatever hangs over it (an entity with a part above its top and over its
    footprint: an opened drawer, not a tall neighbour beside it); and the points of everything else within
    its height band, near enough to be swept through on a way out."""
    own = fill_boxes(view.geom_points(held).reshape(-1, 8, 3))
    bottom, top = own[:, 2].min(), own[:, 2].max()
    footprint = own[:, :2]
    inside = _inside(footprint)
    reach = WAY_OUT_REACH + HAND_HALF_LENGTH
    near_lo, near_hi = footprint.min(axis=0) - reach, footprint.max(axis=0) + reach
    over, band = [np.zeros((0, 3))], [np.zeros((0, 3))]
    for entity in view.objects + view.fixtures:
        corners = view.geom_points(entity)
        boxes = corners.reshape(-1, 8, 3)
        boxes = boxes[np.all((boxes.max(axis=1)[:, :2] >= near_lo) & (boxes.min(axis=1)[:, :2] <= near_hi), axis=1)]
        if entity == held or not len(boxes) or boxes[..., 2].max() <= bottom:
            continue
        points = fill_boxes(boxes)
        points = points[np.all((points[:, :2] >= near_lo) & (points[:, :2] <= near_hi), axis=1)]
        above = points[points[:, 2] > top]
        if inside(above[:, :2]).any():
            over.append(above)
        band.append(points[(points[:, 2] > bottom) & (points[:, 2] <= top)])
    return footprint, inside, np.concatenate(over), np.concatenate(band)


def _inside(footprint: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """A test of which xy points lie within the convex hull of a footprint."""
    from scipy.spatial import ConvexHull, Delaunay

    hull = Delaunay(footprint[ConvexHull(footprint).vertices])
    return lambda points: hull.find_simplex(points) >= 0 if len(points) else np.zeros(0, dtype=bool)


def _hand_overhead(grip: np.ndarray, yaw: float, points: np.ndarray) -> np.ndarray:
    """Points the hand housing would run into rising from `grip` (above it, over its footprint)."""
    above = points[points[:, 2] > grip[2] + HOUSING_ABOVE_GRIP]
    return above[_hand_footprint_distance(grip, yaw, above) < 0]


def headroom(view: SimView, held: str, yaw: float) -> float:
    """How far the held object, and the hand holding it with grasp yaw `yaw`, can rise before touching
    what hangs over them (inf with nothing over them)."""
    _, inside, over, _ = _around_held(view, held)
    top, grip = view.geom_points(held)[:, 2].max(), view.eef_position()
    rooms = [np.inf]
    above_object = over[inside(over[:, :2])]
    if len(above_object):
        rooms.append(float(above_object[:, 2].min() - top))
    above_hand = _hand_overhead(grip, yaw, over)
    if len(above_hand):
        rooms.append(float(above_hand[:, 2].min() - grip[2] - HOUSING_ABOVE_GRIP))
    return min(rooms)


def way_out(view: SimView, held: str, yaw: float) -> np.ndarray | None:
    """The shortest horizontal shift (xy) after which nothing hangs over the held object or the hand
    holding it, within `OVERHANG_GAP`, and that the object makes without sweeping through anything at
    its height; None if there is none within `WAY_OUT_REACH`."""
    from scipy.spatial import cKDTree

    footprint, inside, over, band = _around_held(view, held)
    grip = view.eef_position()
    overhead = np.concatenate([over, band])
    if len(overhead) == 0:
        return np.zeros(2)
    overhead_tree, band_tree = cKDTree(overhead[:, :2]), cKDTree(band[:, :2]) if len(band) else None
    hand_points = over[over[:, 2] > grip[2] + HOUSING_ABOVE_GRIP]

    def clear(shift: np.ndarray) -> bool:
        moved = footprint + shift
        if overhead_tree.query(moved)[0].min() <= OVERHANG_GAP or inside(overhead[:, :2] - shift).any():
            return False
        return (
            len(hand_points) == 0 or _hand_footprint_distance(grip[:2] + shift, yaw, hand_points).min() > OVERHANG_GAP
        )

    def swept_clear(shift: np.ndarray) -> bool:
        steps = np.linspace(0.0, 1.0, max(2, int(np.linalg.norm(shift) / WAY_OUT_STEP) + 1))
        return band_tree is None or all(band_tree.query(footprint + s * shift)[0].min() > 0.0 for s in steps)

    for distance in np.arange(WAY_OUT_STEP, WAY_OUT_REACH + 1e-9, WAY_OUT_STEP):
        for direction in WAY_OUT_DIRECTIONS:
            shift = distance * direction
            if clear(shift) and swept_clear(shift):
                return shift
    return None
