"""Whole-file writes through a temp file in the same directory and `os.replace`.

A reader, or a run resumed after a kill, sees the old file or the new one, never half of one. Every
package writes its outputs (summaries, checkpoints, plots, configs) through here.
"""
from __future__ import annotations

import json
import os
import tempfile
from typing import Any


def atomic_write(path: str | os.PathLike, data: str | bytes) -> None:
    """Atomically replace `path` with `data` (text is UTF-8 encoded)."""
    path = os.fspath(path)
    payload = data.encode() if isinstance(data, str) else data
    fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.", suffix=".tmp", dir=os.path.dirname(os.path.abspath(path)))
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(payload)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def atomic_write_json(path: str | os.PathLike, data: Any) -> None:
    atomic_write(path, json.dumps(data, indent=2, sort_keys=True, default=str) + "\n")
