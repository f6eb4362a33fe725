"""A read-only view of the LIBERO simulator for the constraint code.

Everything the ITCs need (poses, velocities, contacts with normal forces, the gripper, the held object,
goal predicates, region sites) is answered here, so no other package reaches into robosuite or
LIBERO internals. Geoms are mapped once to the scene entity they belong to (a task object, a fixture,
the robot arm, the gripper, the table or the arena), so contact queries speak in task terms.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

ROBOT = "robot"
GRIPPER = "gripper"
ARENA = "arena"
_CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
# Collision geoms of the two fingers (pad and finger body: a grasped can often rests on the finger body).
FINGERS = (
    ("gripper0_finger1_collision", "gripper0_finger1_pad_collision"),
    ("gripper0_finger2_collision", "gripper0_finger2_pad_collision"),
)
PINCH_COS = 0.5  # a finger contact pinches when its normal lies within 60 deg of the closing axis


@dataclass(frozen=True)
class Contact:
    """One active contact between two scene entities, with its normal force in newtons."""

    entity_a: str
    entity_b: str
    geom_a: str
    geom_b: str
    normal_force: float
    position: tuple[float, float, float]

    def involves(self, entity: str) -> bool:
        return entity in (self.entity_a, self.entity_b)

    def other(self, entity: str) -> str:
        return self.entity_b if self.entity_a == entity else self.entity_a


ON_TEST_HEIGHT = 0.10  # LIBERO's On test: an object's origin up to this far above the region's surface
SHELF_TILT = (0.2, 0.95)  # cosines of a support's lean that make it a tilted shelf (not level, not a wall)


@dataclass(frozen=True)
class Region:
    """A BDDL region site: centre, orientation and half-extents (None where LIBERO gives none)."""

    name: str
    parent: str | None
    position: np.ndarray
    rotation: np.ndarray
    half_size: np.ndarray | None

    @property
    def centre(self) -> np.ndarray:
        """Where an object set on the region stands: the site itself, except on a tilted shelf (a wine
        rack's, whose up axis leans ~60 deg), where LIBERO's On test looks up the slope from the site at
        its front edge: the middle of that test's range (`ON_TEST_HEIGHT` above the surface, read
        through the site's rotation as LIBERO reads it). Drawer sites have a level up axis: what goes
        in them is tested against a box around the site instead."""
        up = self.rotation[2]  # LIBERO reads offsets as rotation @ (p - site): this row is its "up"
        if self.half_size is None or not SHELF_TILT[0] < abs(up[2]) < SHELF_TILT[1]:
            return self.position
        return self.position + (float(self.half_size[2]) + ON_TEST_HEIGHT / 2) * up

    @property
    def bottom(self) -> float:
        """World height of the region box's lowest point (a drawer region's: its floor)."""
        return float(self.position[2] - np.abs(self.rotation[2]) @ self.half_size)

    def footprint(self) -> tuple[np.ndarray, np.ndarray | None]:
        """The region's two horizontal axes (world xy unit vectors, one per column) and its half sizes
        along them. Drawer regions come with their local x pointing down and a wine rack's slot with its
        local y up: reading local x and y as the footprint would put a drawer's depth on the vertical."""
        vertical = int(np.argmax(np.abs(self.rotation[2])))
        flat = [i for i in range(3) if i != vertical]
        axes = self.rotation[:2, flat]
        axes = axes / np.linalg.norm(axes, axis=0)
        half = None if self.half_size is None else np.asarray(self.half_size, dtype=float)[flat]
        return axes, half


def _xyzw(wxyz: np.ndarray) -> np.ndarray:
    return np.array([wxyz[1], wxyz[2], wxyz[3], wxyz[0]])


class SimView:
    """Read-only queries on one LIBERO env (the robosuite `BDDLBaseDomain` inside a `ControlEnv`)."""

    def __init__(self, domain) -> None:
        self._domain = domain
        self._model: mujoco.MjModel = domain.sim.model._model
        self._force = np.zeros(6)
        self.objects: tuple[str, ...] = tuple(domain.objects_dict)
        self.fixtures: tuple[str, ...] = tuple(domain.fixtures_dict)
        self.regions: tuple[str, ...] = tuple(domain.object_sites_dict)
        self._body_id = {name: int(domain.obj_body_id[name]) for name in self.objects + self.fixtures}
        self._geom_entity = self._map_geoms_to_entities()
        self._collision_geoms: dict[str, np.ndarray] = {}
        # Ids looked up once: these queries run several times per env step (expert, ITC monitor, obs).
        self._grip_site = self._model.site("gripper0_grip_site").id
        self._hand_body = self._model.body("robot0_right_hand").id
        self._base_body = self._model.body("robot0_base").id
        self._finger_of_geom = {self._model.geom(n).id: side for side, names in enumerate(FINGERS) for n in names}
        self._free_qvel = {
            name: self._model.jnt_dofadr[self._model.joint(domain.get_object(name).joints[0]).id]
            for name in self.objects
            if domain.get_object(name).joints
        }
        self._articulations = {
            name: tuple(domain.get_object(name).joints)
            for name in self.fixtures + self.objects
            if name not in self._free_qvel and domain.get_object(name).joints
        }
        self.table_height = float(domain.workspace_offset[2]) if hasattr(domain, "workspace_offset") else 0.0

    @property
    def _data(self) -> mujoco.MjData:
        # robosuite may rebuild MjData on reset; always read the live one.
        return self._domain.sim.data._data

    def _map_geoms_to_entities(self) -> list[str]:
        model = self._model
        root_to_entity = {}
        for name, body in self._body_id.items():
            root_to_entity[body] = name
        entities = []
        for g in range(model.ngeom):
            body = model.geom_bodyid[g]
            entity = None
            b = body
            while b > 0 and entity is None:
                entity = root_to_entity.get(b)
                b = model.body_parentid[b]
            if entity is None:
                body_name = model.body(body).name
                if body_name.startswith("gripper0"):
                    entity = GRIPPER
                elif body_name.startswith(("robot0", "mount0")):
                    entity = ROBOT
                elif body_name == "table" or model.geom(g).name.startswith("table"):
                    entity = "table"
                else:
                    entity = ARENA
            entities.append(entity)
        return entities

    # ---- poses and motion -------------------------------------------------------------------
    def body_id(self, entity: str) -> int:
        """MuJoCo id of an object's or fixture's root body (what LIBERO places and the poses below read)."""
        return self._body_id[entity]

    def pose(self, entity: str) -> tuple[np.ndarray, np.ndarray]:
        """World position and orientation quaternion (x, y, z, w) of an object or fixture."""
        body = self._body_id[entity]
        return self._data.xpos[body].copy(), _xyzw(self._data.xquat[body])

    def position(self, entity: str) -> np.ndarray:
        return self._data.xpos[self._body_id[entity]].copy()

    def rotation(self, entity: str) -> np.ndarray:
        """3x3 world rotation matrix of an object or fixture."""
        return self._data.xmat[self._body_id[entity]].reshape(3, 3).copy()

    def tilt(self, entity: str) -> float:
        """Angle in radians between the entity's local z axis and world up."""
        return float(np.arccos(np.clip(self.rotation(entity)[2, 2], -1.0, 1.0)))

    def velocity(self, entity: str) -> np.ndarray:
        """Linear velocity (m/s, world frame) of a free-moving object; zeros for fixtures."""
        adr = self._free_qvel.get(entity)
        if adr is None:
            return np.zeros(3)
        return self._data.qvel[adr : adr + 3].copy()

    def geom_points(self, entity: str, body: str | None = None) -> np.ndarray:
        """World-frame corners of the bounding boxes of an entity's collision geoms, shape (8k, 3).

        Cheap shape knowledge for planners and constraints: extents, top height, footprint. With `body`,
        only the geoms of that one body of the entity (a drawer, a knob).
        """
        key = entity if body is None else f"{entity}:{body}"
        geoms = self._collision_geoms.get(key)
        if geoms is None:
            model = self._model
            body_id = None if body is None else model.body(body).id
            geoms = np.array(
                [
                    g
                    for g in range(model.ngeom)
                    if self._geom_entity[g] == entity
                    and (model.geom_contype[g] or model.geom_conaffinity[g])
                    and (body_id is None or model.geom_bodyid[g] == body_id)
                ],
                dtype=int,
            )
            self._collision_geoms[key] = geoms
        data = self._data
        centres = self._model.geom_aabb[geoms, :3]
        halves = self._model.geom_aabb[geoms, 3:]
        local = centres[:, None, :] + halves[:, None, :] * _CORNERS[None]
        rot = data.geom_xmat[geoms].reshape(-1, 3, 3)
        world = np.einsum("gij,gkj->gki", rot, local) + data.geom_xpos[geoms][:, None, :]
        return world.reshape(-1, 3)

    def articulation(self, entity: str) -> np.ndarray:
        """Joint positions of an articulated fixture/object (drawers, doors, knobs); empty otherwise."""
        joints = self._articulations.get(entity, ())
        return np.array([self._data.qpos[self._model.jnt_qposadr[self._model.joint(j).id]] for j in joints])

    def joint(self, name: str) -> dict[str, object]:
        """A joint's current value, world axis and anchor, and the body it moves."""
        model, data = self._model, self._data
        jid = model.joint(name).id
        return {
            "qpos": float(data.qpos[model.jnt_qposadr[jid]]),
            "axis": data.xaxis[jid].copy(),
            "anchor": data.xanchor[jid].copy(),
            "body": model.body(model.jnt_bodyid[jid]).name,
            "range": model.jnt_range[jid].copy(),
        }

    def opening_sign(self, entity: str) -> float:
        """+1 when an articulated fixture or object opens as its joint position grows, -1 when it opens
        as it shrinks, from LIBERO's own open and close ranges: cabinets open towards negative positions,
        and so does the microwave's door, whose hinge axis points up."""
        ranges = self.articulation_ranges(entity)
        return 1.0 if np.mean(ranges["default_open_ranges"]) > np.mean(ranges["default_close_ranges"]) else -1.0

    def open_position(self, entity: str) -> float:
        """The joint position at which LIBERO starts calling an articulated fixture or object open (the
        edge of its open range nearest the closed one)."""
        bounds = self.articulation_ranges(entity)["default_open_ranges"]
        return float(min(bounds) if self.opening_sign(entity) > 0 else max(bounds))

    def articulation_ranges(self, entity: str) -> dict:
        """LIBERO's own open and close ranges of an articulated fixture or object."""
        return {**self._domain.objects_dict, **self._domain.fixtures_dict}[entity].object_properties.get(
            "articulation", {}
        )

    def joint_type(self, name: str) -> str:
        """'free', 'ball', 'slide' or 'hinge'."""
        return ("free", "ball", "slide", "hinge")[int(self._model.jnt_type[self._model.joint(name).id])]

    def articulation_joints(self, target: str) -> tuple[str, ...]:
        """Joints that open/close/turn a region (a drawer) or an articulated entity (a door, a knob)."""
        if target in self.regions:
            joints = self.region_joints(target)
            if joints:
                return joints
            target = self._domain.object_sites_dict[target].parent_name
        return self._articulations.get(target, ())

    def region_joints(self, name: str) -> tuple[str, ...]:
        """The joints a region site itself answers open/close for (a drawer's); none for a region inside
        a hinged fixture (the microwave's heating region), for which LIBERO's open is always False."""
        return tuple(getattr(self._domain.object_sites_dict[name], "joints", ()) or ())

    @property
    def articulated(self) -> dict[str, tuple[str, ...]]:
        return dict(self._articulations)

    def eef_position(self) -> np.ndarray:
        return self._data.site_xpos[self._grip_site].copy()

    def hand_quaternion(self) -> np.ndarray:
        """Orientation (x, y, z, w) of the robot hand body, as robosuite's `robot0_eef_quat`."""
        return _xyzw(self._data.xquat[self._hand_body])

    def eef_rotation(self) -> np.ndarray:
        return self._data.site_xmat[self._grip_site].reshape(3, 3).copy()

    def robot_base_position(self) -> np.ndarray:
        return self._data.xpos[self._base_body].copy()

    def gripper_joints(self) -> np.ndarray:
        """The two finger joint positions (robosuite's `robot0_gripper_qpos`)."""
        return self._data.qpos[self._domain.robots[0]._ref_gripper_joint_pos_indexes].copy()

    def arm_joints(self) -> np.ndarray:
        """The seven arm joint positions (robosuite's `robot0_joint_pos`)."""
        return self._data.qpos[self._domain.robots[0]._ref_joint_pos_indexes].copy()

    def gripper_opening(self) -> float:
        """Distance between the finger joints in metres (about 0.08 open, 0 closed on nothing)."""
        qpos = self.gripper_joints()
        return float(abs(qpos[0]) + abs(qpos[1]))

    # ---- contacts ---------------------------------------------------------------------------
    def contacts(self) -> list[Contact]:
        """Active contacts between different entities with their normal forces."""
        data, model = self._data, self._model
        found = []
        for i in range(data.ncon):
            c = data.contact[i]
            ea, eb = self._geom_entity[c.geom1], self._geom_entity[c.geom2]
            if ea == eb:
                continue
            mujoco.mj_contactForce(model, data, i, self._force)
            found.append(
                Contact(
                    ea, eb, model.geom(c.geom1).name, model.geom(c.geom2).name, float(abs(self._force[0])), tuple(c.pos)
                )
            )
        return found

    def held_object(self) -> str | None:
        """The movable object both fingers pinch, if any: each touches it with the contact pressing along
        the closing axis (within 60 deg). Closed fingertips pressed down on a plate's floor to push it
        touch it with both fingers too, but do not hold it."""
        data = self._data
        closing = self.eef_rotation()[:, 0]
        touching: dict[str, set[int]] = {}
        for i in range(data.ncon):
            c = data.contact[i]
            if abs(float(c.frame[:3] @ closing)) < PINCH_COS:
                continue
            for finger_geom, other in ((c.geom1, c.geom2), (c.geom2, c.geom1)):
                side = self._finger_of_geom.get(finger_geom)
                if side is not None:
                    entity = self._geom_entity[other]
                    if entity in self._free_qvel:
                        touching.setdefault(entity, set()).add(side)
        for entity, sides in touching.items():
            if len(sides) == 2:
                return entity
        return None

    # ---- task semantics ---------------------------------------------------------------------
    def region(self, name: str) -> Region:
        site = self._domain.object_sites_dict[name]
        sid = self._model.site(name).id
        size = getattr(site, "size", None)
        return Region(
            name=name,
            parent=getattr(site, "parent_name", None),
            position=self._data.site_xpos[sid].copy(),
            rotation=self._data.site_xmat[sid].reshape(3, 3).copy(),
            half_size=None if size is None else np.asarray(size, dtype=float),
        )

    def predicate(self, predicate: tuple[str, ...]) -> bool:
        """Truth of one BDDL predicate, e.g. ("on", "bowl_1", "plate_1"), evaluated as LIBERO does."""
        return bool(self._domain._eval_predicate(list(predicate)))
