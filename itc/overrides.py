"""Per-task YAML overrides of the derived constraint spec.

The derivation from BDDL is a heuristic; where it misjudges a task (an object that may be laid down, a
sub-goal order that does not matter), a person writes `<overrides_dir>/<suite>/<task_index>.yaml` with
the fields to replace, for example::

    # libero_10/4: the two mugs may go on their plates in either order
    order: []
    upright: [porcelain_mug_1, white_yellow_mug_1]
    params: {place_xy_tolerance: 0.04}

Every field is validated against the task (entity names, sub-goal indices, parameter names), and a bad
one is refused with the file, the field and what was expected.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

import yaml

from base_suites.runtime.errors import UserInputError
from itc.params import ITCParams
from itc.spec import SURFACES, ConstraintSpec, Scene

ENTITY_FIELDS = ("manipulated", "targets", "supports", "distractors", "idle_fixtures", "upright", "allowed_contacts")
FIELDS = ENTITY_FIELDS + ("order", "params")


def override_path(overrides_dir: str, suite: str, task_index: int) -> str:
    return os.path.join(overrides_dir, suite, f"{int(task_index)}.yaml")


def _entities(path: str, key: str, value: Any, known: tuple[str, ...]) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise UserInputError(f"{path}: field {key!r} must be a list of entity names")
    for name in value:
        if name not in known:
            raise UserInputError(f"{path}: field {key!r}: unknown entity {name!r}; expected one of: {', '.join(known)}")
    return tuple(value)


def _order(path: str, value: Any, n_subgoals: int) -> tuple[tuple[int, int], ...]:
    expected = (
        f"{path}: field 'order' must be a list of [i, j] pairs of sub-goal indices 0..{n_subgoals - 1} with i != j"
    )
    if not isinstance(value, list):
        raise UserInputError(expected)
    pairs = []
    for pair in value:
        ok = (
            isinstance(pair, list)
            and len(pair) == 2
            and all(isinstance(v, int) and not isinstance(v, bool) for v in pair)
            and all(0 <= v < n_subgoals for v in pair)
            and pair[0] != pair[1]
        )
        if not ok:
            raise UserInputError(f"{expected}; got {pair!r}")
        pairs.append((pair[0], pair[1]))
    return tuple(sorted(set(pairs)))


def parse_override(path: str, spec: ConstraintSpec, scene: Scene) -> dict[str, Any]:
    """The validated field changes one override file asks for."""
    try:
        with open(path, encoding="utf-8") as fh:
            data = yaml.safe_load(fh)
    except yaml.YAMLError as exc:
        raise UserInputError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise UserInputError(f"{path}: expected a mapping of spec fields ({', '.join(FIELDS)})")
    changes: dict[str, Any] = {}
    for key, value in data.items():
        if key in ENTITY_FIELDS:
            known = scene.entities + (SURFACES if key == "allowed_contacts" else ())
            changes[key] = _entities(path, key, value, known)
        elif key == "order":
            changes[key] = _order(path, value, len(spec.subgoals))
        elif key == "params":
            if not isinstance(value, dict):
                raise UserInputError(f"{path}: field 'params' must be a mapping of ITC parameter names to numbers")
            ITCParams.from_dict(value, source=f"{path}: field 'params'")
            if "segment_length" in value:
                raise UserInputError(
                    f"{path}: field 'params': segment_length is one value per annotated file, not per task"
                )
            changes[key] = dict(value)
        else:
            raise UserInputError(f"{path}: unknown field {key!r}; expected one of: {', '.join(FIELDS)}")
    return changes


def apply_overrides(spec: ConstraintSpec, scene: Scene, overrides_dir: str) -> ConstraintSpec:
    """The spec with the task's override file applied, if the directory holds one."""
    if not os.path.isdir(overrides_dir):
        raise UserInputError(f"{overrides_dir}: ITC spec overrides directory does not exist")
    path = override_path(overrides_dir, spec.suite, spec.task_index)
    if not os.path.exists(path):
        return spec
    changes = parse_override(path, spec, scene)
    return dataclasses.replace(spec, **changes, overrides=spec.overrides + (path,))
