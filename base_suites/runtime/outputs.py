"""The one rule every command applies to its output path, before any work and before anything is created.

An output is a file (a demo file) or a directory (a run, a policy, a critic). `check_output` refuses in one
line: an empty path, a path under an existing file, a folder that cannot be written, a file where a
directory is expected and the other way round, and a finished result that the call would replace without
`resume` (continue it) or `overwrite` (replace it; a file is replaced only when the new one is complete).
"""

from __future__ import annotations

import os
from typing import Literal

from base_suites.runtime.errors import UserInputError


def check_output(
    path: str | os.PathLike,
    kind: Literal["file", "dir"],
    *,
    resume: bool = False,
    overwrite: bool = False,
    results: tuple[str, ...] = (),
    resumable: bool = True,
) -> str:
    """Check that `path` can be written as a `kind` output; return it as a string. For a directory,
    `results` names the files inside it that make it a finished (or interrupted) result; `resumable`: the
    command has a --resume to suggest."""
    path = os.fspath(path)
    if not path.strip():
        raise UserInputError("the output path is empty")
    if resume and overwrite:
        raise UserInputError(f"{path}: --resume continues an output and --overwrite replaces it; pass one")
    parent = os.path.dirname(os.path.abspath(path))
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise UserInputError(f"{path}: cannot be created, {parent} is a file")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UserInputError(f"{path}: cannot be created, {parent} is not writable")
    if os.path.exists(path):
        if kind == "file" and os.path.isdir(path):
            raise UserInputError(f"{path}: is a directory; expected the path of a file to write")
        if kind == "dir" and not os.path.isdir(path):
            raise UserInputError(f"{path}: exists and is not a directory")
        if not os.access(path, os.W_OK):
            raise UserInputError(f"{path}: is not writable")
    # a file's result is the file or the journal of an interrupted writer (`<path>.partial`)
    held = (path, path + ".partial") if kind == "file" else tuple(os.path.join(path, name) for name in results)
    found = [f for f in held if os.path.exists(f)]
    if found and not (resume or overwrite):
        continuing = "--resume to continue it, " if resumable else ""
        raise UserInputError(f"{found[0]}: exists; pass {continuing}--overwrite to replace it, or choose another path")
    return path


def remove_results(path: str | os.PathLike, names: tuple[str, ...]) -> None:
    """Remove the result files `names` of the directory `path` (an `overwrite` starting afresh)."""
    for name in names:
        target = os.path.join(os.fspath(path), name)
        if os.path.exists(target):
            os.remove(target)
