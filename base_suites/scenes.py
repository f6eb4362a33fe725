"""LIBERO's five built-in scenes, and a task's BDDL moved from its scene into another one.

LIBERO-PRO's environment axis substitutes one built-in scene for another (its `EnvironmentReplace`
perturbation): the BDDL problem class (which arena, table height, robot mount and cameras) changes, and the
workspace fixture (the table, or the floor) is renamed everywhere the task places something on it. Objects,
fixtures, goal and instruction stay. The shipped init states belong to the old scene, so an env built from
a moved task samples its starts from the BDDL's placement regions (`LiberoEnv`, design §4.2-4.3).
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile

from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import atomic_write

# workspace fixture -> (the token of its BDDL problem class, the fixture's BDDL category); LIBERO-PRO's set
# (the coffee table, which none of the four 10-task suites uses, is not among its substitutes)
SCENES: dict[str, tuple[str, str]] = {
    "main_table": ("Tabletop", "table"),
    "kitchen_table": ("Kitchen_Tabletop", "kitchen_table"),
    "living_room_table": ("Living_Room_Tabletop", "living_room_table"),
    "study_table": ("Study_Tabletop", "study_table"),
    "floor": ("Floor", "floor"),
}
_PROBLEM = re.compile(r"\(define\s*\(problem\s+LIBERO_(\w+?)_Manipulation\)")


def scene_of(bddl_text: str, source: str = "BDDL") -> str:
    """The workspace fixture of a task's scene ("main_table", "floor", ...), from its problem class."""
    match = _PROBLEM.search(bddl_text)
    by_token = {token: scene for scene, (token, _) in SCENES.items()}
    if match is None or match.group(1) not in by_token:
        found = match.group(1) if match else "no LIBERO problem class"
        raise UserInputError(
            f"{source}: scene {found!r} is not one of LIBERO's replaceable scenes ({', '.join(SCENES)})"
        )
    return by_token[match.group(1)]


def move_to_scene(bddl_text: str, scene: str, source: str = "BDDL") -> str:
    """The BDDL text with its task moved into `scene`: the problem class, the workspace fixture's name and
    category, every region defined on it (`:target`) and every reference to such a region (`<fixture>_<region>`).
    The language block is left as it is."""
    if scene not in SCENES:
        raise UserInputError(f"{source}: unknown scene {scene!r}; expected one of {', '.join(SCENES)}")
    old = scene_of(bddl_text, source)
    if scene == old:
        return bddl_text
    language = re.search(r"\(:language[^)]*\)", bddl_text)
    head, lang, tail = (
        (bddl_text[: language.start()], language.group(0), bddl_text[language.end() :])
        if language
        else (bddl_text, "", "")
    )
    regions = re.findall(rf"\((\w+)\s*\(:target\s+{old}\s*\)", bddl_text)
    token, category = SCENES[scene]

    def moved(text: str) -> str:
        text = _PROBLEM.sub(f"(define (problem LIBERO_{token}_Manipulation)", text, count=1)
        text = re.sub(rf"\(:target\s+{old}\s*\)", f"(:target {scene})", text)
        text = re.sub(rf"(?m)^(\s*){old}\s*-\s*{SCENES[old][1]}\s*$", rf"\g<1>{scene} - {category}", text)
        for region in regions:
            text = re.sub(rf"\b{old}_{region}\b", f"{scene}_{region}", text)
        return text

    return moved(head) + lang + moved(tail)


def scene_bddl_file(bddl_file: str, scene: str) -> str:
    """A BDDL file of the task in `bddl_file` moved into `scene`, written once into a shared cache folder
    named by its content (atomic, so parallel workers may race to write the same file)."""
    with open(bddl_file, encoding="utf-8") as f:
        text = move_to_scene(f.read(), scene, bddl_file)
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    folder = os.path.join(tempfile.gettempdir(), "libero-elegant-scenes")
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, f"{os.path.splitext(os.path.basename(bddl_file))[0]}.{scene}.{digest}.bddl")
    if not os.path.exists(path):
        atomic_write(path, text)
    return path
