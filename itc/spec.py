"""The per-task constraint spec: what each criterion treats as target, support, distractor, upright.

Derived from the task's BDDL alone (no simulator): the goal predicates give the sub-goals, the objects
they move (`manipulated`) and where to (`placements`, `targets`); the initial state gives what those
objects stand on (`supports`); every other movable object is a `distractor`, every fixture the task does
not name an `idle_fixture`; object categories that stand upright (bottles, mugs, bowls, cans, ...) are
`upright`. The sub-goal `order` is the order BDDL lists them in (LIBERO writes goals in the order the
instruction states them), corrected by physical dependencies (a drawer is opened before something goes
in and closed after; a stack is built before it is moved) and relaxed where the instruction says "both".
A YAML file per task can replace any of these fields (see `itc.overrides`).
"""

from __future__ import annotations

import functools
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from base_suites._libero import libero_modules, quietly
from base_suites.suites import TaskSpec, get_task
from itc.params import ITCParams

# SimView's names for the static scene that objects stand on (LIBERO tables, the floor, the arena).
SURFACES = ("table", "arena")
# Object categories that stand upright and must stay so (matched as substrings of the BDDL category).
UPRIGHT_KEYWORDS = (
    "bowl",
    "mug",
    "cup",
    "bottle",
    "ketchup",
    "sauce",
    "soup",
    "dressing",
    "milk",
    "juice",
    "moka_pot",
    "ramekin",
)
# Upright objects too tall for a drawer and bottles bound for a wine rack can only reach their goal lying
# down, so the upright check would flag every success there.
TALL_KEYWORDS = ("bottle", "ketchup", "dressing", "milk", "juice")
_DRAWER = re.compile(r"_(top|middle|bottom)_region$")
ARTICULATION_PREDICATES = ("open", "close", "turnon", "turnoff")
PLACEMENT_PREDICATES = ("on", "in")


def format_predicate(predicate: tuple[str, ...]) -> str:
    return f"{predicate[0]}({', '.join(predicate[1:])})"


@dataclass(frozen=True)
class Placement:
    """An on/in sub-goal that puts a movable object onto or into a target."""

    subgoal: int
    obj: str
    target: str
    """The BDDL name of the target: an object (plate_1) or a region (basket_1_contain_region)."""
    target_entity: str | None
    """The object or fixture owning the target; None for a region of the table or floor."""
    target_is_region: bool


@dataclass(frozen=True)
class ConstraintSpec:
    """Which scene entities each ITC treats how, for one task."""

    suite: str
    task_index: int
    task_name: str
    instruction: str
    subgoals: tuple[tuple[str, ...], ...]
    order: tuple[tuple[int, int], ...]
    """(i, j): sub-goal i must be reached before sub-goal j."""
    placements: tuple[Placement, ...]
    manipulated: tuple[str, ...]
    targets: tuple[str, ...]
    supports: tuple[str, ...]
    distractors: tuple[str, ...]
    idle_fixtures: tuple[str, ...]
    upright: tuple[str, ...]
    allowed_contacts: tuple[str, ...] = ()
    """Extra entities the robot may touch (set by overrides)."""
    params: Mapping[str, Any] = field(default_factory=dict, hash=False)
    """Per-task ITC parameter changes (set by overrides); they win over the caller's parameters."""
    overrides: tuple[str, ...] = ()
    """The override files applied."""

    @property
    def task_key(self) -> str:
        return f"{self.suite}/{self.task_index}"

    def effective_params(self, base: ITCParams | None = None) -> ITCParams:
        return (base or ITCParams()).updated(self.params, source=f"spec overrides of {self.task_key}")

    def robot_may_touch(self) -> frozenset[str]:
        """Entities robot contact with is part of the task: what it moves, where to, what it stands on."""
        return frozenset(self.manipulated + self.targets + self.supports + self.allowed_contacts + SURFACES)

    def to_dict(self) -> dict[str, Any]:
        """A printable, YAML/JSON-friendly description (what `elegant itc-spec` shows)."""
        return {
            "task": self.task_key,
            "task_name": self.task_name,
            "instruction": self.instruction,
            "subgoals": [format_predicate(p) for p in self.subgoals],
            "order": [[i, j] for i, j in self.order],
            "order_readable": [
                f"{format_predicate(self.subgoals[i])} before {format_predicate(self.subgoals[j])}"
                for i, j in self.order
            ],
            "placements": [
                {"object": p.obj, "target": p.target, "target_entity": p.target_entity, "region": p.target_is_region}
                for p in self.placements
            ],
            "manipulated": list(self.manipulated),
            "targets": list(self.targets),
            "supports": list(self.supports),
            "distractors": list(self.distractors),
            "idle_fixtures": list(self.idle_fixtures),
            "upright": list(self.upright),
            "allowed_contacts": list(self.allowed_contacts),
            "params": dict(self.params),
            "overrides": list(self.overrides),
        }


@dataclass(frozen=True)
class Scene:
    """The parts of a BDDL problem the spec is derived from."""

    objects: dict[str, str]
    """instance -> category of every movable object."""
    fixtures: dict[str, str]
    """instance -> category of every fixture, including tables and the floor."""
    regions: dict[str, str]
    """region name -> the instance it is defined on (BDDL's :target)."""
    initial_state: tuple[tuple[str, ...], ...]

    def is_surface(self, name: str) -> bool:
        category = self.fixtures.get(name, "")
        return category == "floor" or category.endswith("table")

    @property
    def entities(self) -> tuple[str, ...]:
        """Objects and fixtures as SimView names them (tables and floor are SimView's SURFACES)."""
        return tuple(self.objects) + tuple(f for f in self.fixtures if not self.is_surface(f))

    def owner(self, name: str) -> str | None:
        """The object or fixture a BDDL name belongs to; None for the table/floor and their regions."""
        if name in self.objects:
            return name
        if name in self.fixtures:
            return None if self.is_surface(name) else name
        if name in self.regions:
            return self.owner(self.regions[name])
        prefixes = [e for e in self.entities if name.startswith(e + "_")]
        return max(prefixes, key=len) if prefixes else None

    def category(self, name: str) -> str:
        return self.objects.get(name) or self.fixtures.get(name, "")


@functools.cache
def load_scene(bddl_file: str) -> Scene:
    libero_modules()  # headless defaults and quiet robosuite import come first
    from libero.libero.envs.bddl_utils import robosuite_parse_problem

    parsed = quietly(robosuite_parse_problem, bddl_file)
    return Scene(
        objects={inst: cat for cat, insts in parsed["objects"].items() for inst in insts},
        fixtures={inst: cat for cat, insts in parsed["fixtures"].items() for inst in insts},
        regions={name: region["target"] for name, region in parsed["regions"].items()},
        initial_state=tuple(tuple(p) for p in parsed["initial_state"]),
    )


def _unique(names) -> tuple[str, ...]:
    return tuple(dict.fromkeys(n for n in names if n is not None))


def _contains(scene: Scene, region: str, container: str) -> bool:
    """Whether `region` is `container` itself or one of its regions (a drawer named by its cabinet)."""
    return region == container or (container in scene.entities and scene.owner(region) == container)


def _dependencies(scene: Scene, goals: tuple[tuple[str, ...], ...]) -> set[tuple[int, int]]:
    deps = set()
    for i, a in enumerate(goals):
        for j, b in enumerate(goals):
            if i == j:
                continue
            opens_for = a[0] == "open" and b[0] == "in" and _contains(scene, b[2], a[1])
            closes_after = a[0] == "in" and b[0] == "close" and _contains(scene, a[2], b[1])
            stacks_before_moving = a[0] == "on" and b[0] in PLACEMENT_PREDICATES and b[1] == a[2]
            if opens_for or closes_after or stacks_before_moving:
                deps.add((i, j))
    return deps


def derive_order(scene: Scene, goals: tuple[tuple[str, ...], ...], instruction: str) -> tuple[tuple[int, int], ...]:
    """Precedence pairs: BDDL order, overruled by physical dependencies, relaxed within a "both" group."""
    deps = _dependencies(scene, goals)
    both = re.search(r"\bboth\b", instruction.lower()) is not None

    def same_group(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
        return both and a[0] == b[0] and a[0] in PLACEMENT_PREDICATES and a[2] == b[2]

    pairs = set(deps)
    for i in range(len(goals)):
        for j in range(i + 1, len(goals)):
            if (j, i) not in deps and not same_group(goals[i], goals[j]):
                pairs.add((i, j))
    return tuple(sorted(pairs))


def _lies_at_goal(scene: Scene, obj: str, placements: tuple[Placement, ...]) -> bool:
    category = scene.category(obj)
    if not any(k in category for k in TALL_KEYWORDS):
        return False
    for p in placements:
        if p.obj == obj and p.target_entity is not None:
            into_drawer = (
                p.target_is_region and "cabinet" in scene.category(p.target_entity) and _DRAWER.search(p.target)
            )
            if into_drawer or "wine_rack" in scene.category(p.target_entity):
                return True
    return False


def _task_of(task_or_env) -> TaskSpec:
    if isinstance(task_or_env, TaskSpec):
        return task_or_env
    env = getattr(task_or_env, "unwrapped", task_or_env)
    task = getattr(env, "task", None)
    if not isinstance(task, TaskSpec):
        raise TypeError(f"expected a base_suites.TaskSpec or a LIBERO env, got {type(task_or_env).__name__}")
    return task


def derive_spec(task_or_env, overrides_dir: str | None = None) -> ConstraintSpec:
    """The constraint spec of a task (a `TaskSpec` or an env built by `make_env`), plus YAML overrides."""
    task = _task_of(task_or_env)
    instruction = getattr(getattr(task_or_env, "unwrapped", None), "instruction", task.language)
    scene = load_scene(task.bddl_file)
    goals = tuple(tuple(p) for p in task.goal)
    placements = tuple(
        Placement(i, p[1], p[2], scene.owner(p[2]), p[2] not in scene.objects and p[2] not in scene.fixtures)
        for i, p in enumerate(goals)
        if p[0] in PLACEMENT_PREDICATES and p[1] in scene.objects
    )
    manipulated = _unique(p.obj for p in placements)
    targets = _unique(
        [p.target_entity for p in placements] + [scene.owner(p[1]) for p in goals if p[0] in ARTICULATION_PREDICATES]
    )
    supports = _unique(
        scene.owner(p[2])
        for p in scene.initial_state
        if p[0] in PLACEMENT_PREDICATES and len(p) == 3 and p[1] in manipulated
    )
    named = set(manipulated) | set(targets)
    spec = ConstraintSpec(
        suite=task.suite,
        task_index=task.index,
        task_name=task.name,
        instruction=instruction,
        subgoals=goals,
        order=derive_order(scene, goals, task.language),
        placements=placements,
        manipulated=manipulated,
        targets=targets,
        supports=supports,
        distractors=tuple(o for o in scene.objects if o not in named),
        idle_fixtures=tuple(f for f in scene.entities if f in scene.fixtures and f not in named and f not in supports),
        upright=tuple(
            o
            for o in scene.objects
            if any(k in scene.category(o) for k in UPRIGHT_KEYWORDS) and not _lies_at_goal(scene, o, placements)
        ),
    )
    if overrides_dir is not None:
        from itc.overrides import apply_overrides

        spec = apply_overrides(spec, scene, overrides_dir)
    return spec


def describe_spec(suite: str, task: int | str, overrides_dir: str | None = None) -> dict[str, Any]:
    """The printable spec of one task, for the CLI (`elegant itc-spec SUITE TASK`)."""
    return derive_spec(get_task(suite, task), overrides_dir).to_dict()
