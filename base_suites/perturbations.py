"""LIBERO-PRO perturbations as seeded, composable operators.

Four axes, as in LIBERO-PRO: `object` (the task objects: colours, `@texture` their textures, or
`@scale` their size), `init` (task objects moved 0.2-0.3 m;
or, `init@nudge`, up to 2 cm: fresh starts, not a robustness test), `language` (paraphrased or target-swapped
instruction) and `env` (floor, wall and table swap; or, `env@replace`, LIBERO-PRO's substitution of
another built-in scene); and LIBERO-PRO's language probe, `probe` (the
instruction shuffled, replaced by an unrelated one, or emptied). Each operator acts at the stage where the
change belongs: before the env is built (which BDDL file, which instruction, which scene textures), right
after it is built (colours), or after every reset (positions). The package's shipped LIBERO-PRO variants are
used where they exist (`mode="shipped"`); by default new variants are generated from the seed, so the number
of distinct perturbed tasks is unbounded. What each operator did is returned by `describe()` and recorded
in `info` and episode metadata.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from base_suites.runtime.errors import UserInputError, unknown_choice
from base_suites.suites import PRO_SUITES, TaskSpec, base_suite_of, get_task

FLOOR_STYLES = (
    "dark",
    "rustic",
    "light-gray",
    "white-marble",
    "wood-plank",
    "brown-ceramic",
    "gray-ceramic",
    "tile_grigia_caldera",
)
WALL_STYLES = (
    "light-blue",
    "dark-blue",
    "dark-gray-plaster",
    "gray-plaster",
    "dark-green",
    "light-gray-plaster",
    "ceramic",
    "white",
    "yellow-linen",
)


@dataclass
class BuildPlan:
    """What the env factory needs before it builds the simulator."""

    task: TaskSpec
    instruction: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)


class Perturbation:
    """Base operator: seeded; each hook is a no-op unless the axis needs it."""

    axis: ClassVar[str] = ""
    modes: ClassVar[tuple[str, ...]] = ("generated",)

    def __init__(self, seed: int = 0, mode: str | None = None) -> None:
        self.seed = int(seed)
        self.mode = mode or self.modes[0]
        if self.mode not in self.modes:
            raise unknown_choice(f"mode of perturbation {self.axis!r}", self.mode, self.modes)
        self._record: dict[str, Any] = {"axis": self.axis, "seed": self.seed, "mode": self.mode}

    def rng(self, salt: int = 0) -> np.random.Generator:
        return np.random.default_rng([self.seed, salt, sum(map(ord, self.axis))])

    def plan(self, plan: BuildPlan) -> BuildPlan:
        return plan

    def after_build(self, domain) -> None:
        pass

    def after_reset(self, domain, episode_seed: int) -> None:
        pass

    def describe(self) -> dict[str, Any]:
        return dict(self._record)

    @property
    def samples_starts(self) -> bool:
        """Whether the env must sample its starts from the BDDL's placement regions (the shipped init
        states do not fit the scene this operator builds)."""
        return False

    @property
    def robustness_axis(self) -> str:
        """The column a run under this operator reports in (`elegant report`): the axis, with its mode when
        it is not the generated default ("language@shipped" and "language@target_swap" are different
        LIBERO-PRO axes; a generated and a shipped run of one axis are different variants)."""
        return self.axis if self.mode == self.modes[0] else f"{self.axis}@{self.mode}"


def _shipped_variant(task: TaskSpec, axis: str) -> TaskSpec:
    suite = f"{base_suite_of(task.suite)}_{axis}"
    if suite not in PRO_SUITES:
        raise UserInputError(f"suite {task.suite!r} has no shipped LIBERO-PRO '{axis}' variant")
    return get_task(suite, task.index)


def _entity_materials(domain, entity: str) -> list[int]:
    """Material ids used by the visual geoms of one object or fixture."""
    model = domain.sim.model._model
    root = int(domain.obj_body_id[entity])
    mats = set()
    for g in range(model.ngeom):
        b = model.geom_bodyid[g]
        while b > 0 and b != root:
            b = model.body_parentid[b]
        if b == root and model.geom_matid[g] >= 0:
            mats.add(int(model.geom_matid[g]))
    return sorted(mats)


def _task_entities(domain) -> list[str]:
    """Objects and fixtures the task names (regions resolve to the entity that owns them)."""
    names = []
    for name in domain.obj_of_interest:
        if name in domain.obj_body_id:
            names.append(name)
        elif name in domain.object_sites_dict:
            parent = domain.object_sites_dict[name].parent_name
            if parent in domain.obj_body_id:
                names.append(parent)
    return list(dict.fromkeys(names))


class ObjectPerturbation(Perturbation):
    """Task objects change appearance or size: new colours (generated), another texture of the scene on each
    of their textured materials (texture), each movable task object grown by 1.1-1.2 (scale; not one the
    goal stows inside a fixture, whose interior fits its own size), or LIBERO-PRO's object swaps (shipped)."""

    axis = "object"
    modes = ("generated", "texture", "scale", "shipped")
    # grown only, by as much as keeps every task solvable by the scripted expert and the objects graspable
    # by the Panda's gripper (shrinking did not: docs/lab/robustness-axes.md)
    scale_range = (1.1, 1.2)

    def plan(self, plan: BuildPlan) -> BuildPlan:
        if self.mode == "shipped":
            variant = _shipped_variant(plan.task, "object")
            self._record["suite"] = variant.suite
            return BuildPlan(variant, plan.instruction, plan.env_kwargs)
        return plan

    def after_build(self, domain) -> None:
        if self.mode == "generated":
            self._recolour(domain)
        elif self.mode == "texture":
            self._retexture(domain)
        elif self.mode == "scale":
            self._rescale(domain)

    def after_reset(self, domain, episode_seed: int) -> None:
        if self.mode == "scale":
            _rest_scaled_objects(domain, self._record["scales"])

    def _rescale(self, domain) -> None:
        from base_suites.model_scaling import scale_subtree

        rng = self.rng(2)
        model, data = domain.sim.model._model, domain.sim.data._data
        scales = {}
        stowed = {  # objects the goal puts inside a fixture (a drawer): its interior fits their own size
            p[1]
            for p in domain.parsed_problem["goal_state"]
            if p[0] == "in"
            and p[2] in domain.object_sites_dict
            and domain.object_sites_dict[p[2]].parent_name in domain.fixtures_dict
        }
        for entity in _task_entities(domain):
            if entity not in domain.objects_dict or not domain.objects_dict[entity].joints or entity in stowed:
                continue  # fixtures (cabinets, stoves) keep their size: their joints and regions are calibrated
            factor = float(rng.uniform(*self.scale_range))
            scale_subtree(model, data, int(domain.obj_body_id[entity]), factor)
            for site in domain.object_sites_dict.values():  # LIBERO checks `In` against its own copy of sizes
                if site.parent_name == entity:
                    site.size = np.asarray(site.size, dtype=float) * factor
            scales[entity] = round(factor, 4)
        self._record["scales"] = scales

    def _recolour(self, domain) -> None:
        rng = self.rng()
        model = domain.sim.model._model
        colours = {}
        for entity in _task_entities(domain):
            rgb = rng.uniform(0.15, 1.0, size=3)
            for mat in _entity_materials(domain, entity):
                model.mat_rgba[mat, :3] = rgb
            colours[entity] = [round(float(c), 3) for c in rgb]
        self._record["colours"] = colours

    def _retexture(self, domain) -> None:
        import mujoco

        rng = self.rng(1)
        model = domain.sim.model._model
        rgb_role = int(mujoco.mjtTextureRole.mjTEXROLE_RGB)
        flat = [t for t in range(model.ntex) if model.tex_type[t] == mujoco.mjtTexture.mjTEXTURE_2D]
        textures = {}
        for entity in _task_entities(domain):
            materials = [m for m in _entity_materials(domain, entity) if model.mat_texid[m, rgb_role] >= 0]
            own = {int(model.mat_texid[m, rgb_role]) for m in materials}
            others = [t for t in flat if t not in own]
            if not materials or not others:
                continue
            chosen = []
            for mat in materials:
                texture = others[rng.integers(len(others))]
                model.mat_texid[mat, rgb_role] = texture
                chosen.append(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_TEXTURE, texture))
            textures[entity] = chosen
        self._record["textures"] = textures


def _rest_scaled_objects(domain, scales: dict[str, float]) -> None:
    """Move each resized object vertically so that its lowest point is where the unresized object's was
    (resizing about the body origin would sink a grown object into its support, or drop a shrunk one)."""
    import mujoco

    from base_suites.sim_view import SimView

    model, data = domain.sim.model._model, domain.sim.data._data
    mujoco.mj_forward(model, data)
    view = SimView(domain)
    for entity, factor in scales.items():
        origin_z = view.position(entity)[2]
        lowest = view.geom_points(entity)[:, 2].min()
        adr = model.jnt_qposadr[model.joint(domain.objects_dict[entity].joints[0]).id]
        data.qpos[adr + 2] += (origin_z + (lowest - origin_z) / factor) - lowest
    mujoco.mj_forward(model, data)


class InitPerturbation(Perturbation):
    """Task objects start 0.2-0.3 m away from their shipped positions, on reachable free table space.

    Mode "nudge" moves them 0-2 cm instead: not a robustness test but a supply of starts beyond the 50
    init states LIBERO ships per task, for a critic's training rollouts.
    """

    axis = "init"
    modes = ("generated", "shipped", "nudge")
    shift_range = {"generated": (0.2, 0.3), "nudge": (0.0, 0.02)}  # metres, per mode
    clearance = 0.08  # minimum xy distance between object centres
    reach = (0.3, 0.85)  # xy distance from the robot base that the arm reaches comfortably
    max_tries = 200

    @property
    def margin(self) -> float:
        """How far apart two footprints must stay (xy, along some axis)."""
        return self.clearance / 4

    def plan(self, plan: BuildPlan) -> BuildPlan:
        if self.mode == "shipped":
            variant = _shipped_variant(plan.task, "swap")
            self._record["suite"] = variant.suite
            return BuildPlan(variant, plan.instruction, plan.env_kwargs)
        return plan

    def after_reset(self, domain, episode_seed: int) -> None:
        if self.mode not in self.shift_range:
            return
        import mujoco

        from base_suites.sim_view import SimView

        view = SimView(domain)
        rng = self.rng(episode_seed)
        model, data = domain.sim.model._model, domain.sim.data._data
        base = view.robot_base_position()[:2]
        movable = {n: domain.objects_dict[n].joints[0] for n in view.objects if domain.objects_dict[n].joints}
        boxes = {}
        for name in view.objects + view.fixtures:
            pts = view.geom_points(name)
            if len(pts):
                boxes[name] = (pts[:, :2].min(axis=0), pts[:, :2].max(axis=0))
        centres = np.array([(lo + hi) / 2 for lo, hi in boxes.values()])
        area = (centres.min(axis=0) - 0.1, centres.max(axis=0) + 0.1)
        shifts = {}
        for name in (n for n in _task_entities(domain) if n in movable and n in boxes):
            others = {k: v for k, v in boxes.items() if k != name}
            if self.mode == "nudge":  # keep the shipped start's contacts (a bowl on a plate); make no new ones
                others = {k: v for k, v in others.items() if _apart(boxes[name], v, self.margin)}
            delta = self._draw_shift(rng, boxes[name], others, base, area)
            adr = model.jnt_qposadr[model.joint(movable[name]).id]
            data.qpos[adr : adr + 2] += delta
            boxes[name] = (boxes[name][0] + delta, boxes[name][1] + delta)
            shifts[name] = [round(float(v), 4) for v in delta]
        mujoco.mj_forward(model, data)
        self._record["shifts"] = shifts

    def _draw_shift(self, rng, box, others, base, area) -> np.ndarray:
        """A shift in the mode's `shift_range` that keeps the object's footprint within reach, inside the
        scene's area and clear (by `margin`) of every footprint in `others`."""
        lo, hi = box
        for _ in range(self.max_tries):
            angle = rng.uniform(0, 2 * np.pi)
            delta = rng.uniform(*self.shift_range[self.mode]) * np.array([np.cos(angle), np.sin(angle)])
            new_lo, new_hi = lo + delta, hi + delta
            centre = (new_lo + new_hi) / 2
            if not (self.reach[0] <= np.linalg.norm(centre - base) <= self.reach[1]):
                continue
            if np.any(centre < area[0]) or np.any(centre > area[1]):
                continue
            if all(_apart((new_lo, new_hi), other, self.margin) for other in others.values()):
                return delta
        low, high = self.shift_range[self.mode]
        raise RuntimeError(f"no free reachable placement {low}-{high} m away after {self.max_tries} tries")


def _apart(box, other, margin: float) -> bool:
    """Whether two xy footprints (lo, hi corners) are more than `margin` apart along some axis."""
    return bool(np.any(box[0] > other[1] + margin) or np.any(box[1] < other[0] - margin))


_SYNONYMS = {
    r"\bpick up\b": ("grab", "take", "lift", "pick up"),
    r"\bpick\b": ("grab", "take", "lift"),
    r"\bplace\b": ("put", "set", "leave"),
    r"\bput\b": ("place", "set", "move"),
    r"\bin the\b": ("into the", "inside the", "in the"),
    r"\bon the\b": ("onto the", "on top of the", "on the"),
    r"\bopen\b": ("pull open", "open up", "open"),
    r"\bclose\b": ("shut", "push closed", "close"),
    r"\bturn on\b": ("switch on", "turn on"),
    r"\bturn off\b": ("switch off", "turn off"),
    r"\bpush\b": ("slide", "shove", "push"),
}
_TEMPLATES = ("{}", "please {}", "{} now", "can you {}?", "your task: {}", "{}, carefully", "go ahead and {}")


def paraphrase(instruction: str, rng: np.random.Generator) -> str:
    """A seeded paraphrase: verb and preposition synonyms plus a framing template."""
    text = instruction.strip().lower()
    for pattern, options in _SYNONYMS.items():
        text = re.sub(pattern, lambda _m, o=options: o[rng.integers(len(o))], text)
    return _TEMPLATES[rng.integers(len(_TEMPLATES))].format(text)


class LanguagePerturbation(Perturbation):
    """The instruction is paraphrased (generated or LIBERO-PRO's), or its target swapped (LIBERO-PRO task)."""

    axis = "language"
    modes = ("generated", "shipped", "target_swap")

    def plan(self, plan: BuildPlan) -> BuildPlan:
        self._record["original"] = plan.instruction
        if self.mode == "generated":
            new = BuildPlan(plan.task, paraphrase(plan.instruction, self.rng()), plan.env_kwargs)
        else:
            variant = _shipped_variant(plan.task, "lan" if self.mode == "shipped" else "task")
            self._record["suite"] = variant.suite
            new = BuildPlan(variant, variant.language, plan.env_kwargs)
        self._record["instruction"] = new.instruction
        return new


class ProbePerturbation(Perturbation):
    """The language probe (LIBERO-PRO's evidence that policies ignore the instruction): the task and scene
    stay, the instruction is corrupted: its words shuffled, replaced by another LIBERO task's instruction
    (from libero_90, a different one), or emptied. A policy that succeeds as often under the probe as
    without it did not use the instruction."""

    axis = "probe"
    modes = ("shuffled", "unrelated", "empty")

    def plan(self, plan: BuildPlan) -> BuildPlan:
        self._record["original"] = plan.instruction
        rng = self.rng()
        if self.mode == "shuffled":
            words = plan.instruction.split()
            order = rng.permutation(len(words))
            if len(set(words)) > 1:
                while [words[i] for i in order] == words:
                    order = rng.permutation(len(words))
            instruction = " ".join(words[i] for i in order)
        elif self.mode == "unrelated":
            from base_suites.suites import list_tasks

            others = sorted({t.language for t in list_tasks("libero_90")} - {plan.instruction})
            instruction = others[rng.integers(len(others))]
        else:
            instruction = ""
        self._record["instruction"] = instruction
        return BuildPlan(plan.task, instruction, plan.env_kwargs)


class EnvPerturbation(Perturbation):
    """The scene changes around the task. Generated: floor and wall textures swapped, the table recoloured.
    Replace (LIBERO-PRO's environment axis): the task moves into another of LIBERO's five built-in scenes
    (`base_suites.scenes`), drawn per task from the seed; its starts are sampled from the BDDL's placement
    regions, since the shipped init states belong to the old scene."""

    axis = "env"
    modes = ("generated", "replace")

    @property
    def samples_starts(self) -> bool:
        return self.mode == "replace"

    def plan(self, plan: BuildPlan) -> BuildPlan:
        if self.mode == "replace":
            return self._replace_scene(plan)
        rng = self.rng()
        style = {
            "floor_style": FLOOR_STYLES[rng.integers(len(FLOOR_STYLES))],
            "wall_style": WALL_STYLES[rng.integers(len(WALL_STYLES))],
        }
        self._record.update(style)
        return BuildPlan(plan.task, plan.instruction, {**plan.env_kwargs, "scene_properties": style})

    def _replace_scene(self, plan: BuildPlan) -> BuildPlan:
        from base_suites.scenes import SCENES, scene_bddl_file, scene_of
        from base_suites.suites import with_bddl

        with open(plan.task.bddl_file, encoding="utf-8") as f:
            current = scene_of(f.read(), plan.task.bddl_file)
        others = [scene for scene in SCENES if scene != current]
        scene = others[self.rng(plan.task.index).integers(len(others))]
        self._record.update(original_scene=current, scene=scene)
        task = with_bddl(plan.task, scene_bddl_file(plan.task.bddl_file, scene))
        return BuildPlan(task, plan.instruction, plan.env_kwargs)

    def after_build(self, domain) -> None:
        if self.mode == "replace":
            return
        model = domain.sim.model._model
        rgb = self.rng(1).uniform(0.2, 1.0, size=3)
        table_mats = {
            int(model.geom_matid[g])
            for g in range(model.ngeom)
            if model.geom_matid[g] >= 0
            and model.body(model.geom_bodyid[g]).name in ("table", "coffee_table", "study_table")
        }
        for mat in table_mats:
            model.mat_rgba[mat, :3] = rgb
        self._record["table_rgb"] = [round(float(c), 3) for c in rgb]


PERTURBATIONS: dict[str, type[Perturbation]] = {
    cls.axis: cls
    for cls in (ObjectPerturbation, InitPerturbation, LanguagePerturbation, EnvPerturbation, ProbePerturbation)
}


def make_perturbation(axis: str, seed: int = 0, mode: str | None = None) -> Perturbation:
    """Look an operator up by axis name."""
    if axis not in PERTURBATIONS:
        raise unknown_choice("perturbation axis", axis, PERTURBATIONS)
    return PERTURBATIONS[axis](seed=seed, mode=mode)


def parse_perturbations(text: str | None, default_seed: int = 0) -> list[Perturbation]:
    """Parse `axis[:seed][@mode]` items separated by commas, e.g. "init:3,language@shipped"."""
    if not text:
        return []
    found = []
    for item in text.split(","):
        item = item.strip()
        m = re.fullmatch(r"([a-z_]+)(?::(\d+))?(?:@([a-z_]+))?", item)
        if m is None:
            raise UserInputError(f"perturbation {item!r}: expected axis[:seed][@mode], e.g. init:3 or language@shipped")
        axis, seed, mode = m.groups()
        found.append(make_perturbation(axis, int(seed) if seed is not None else default_seed, mode))
    return found
