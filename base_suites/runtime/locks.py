"""One writer per output: an advisory lock beside each output a command writes.

`output_lock(path)` holds an exclusive `flock` on `<path>.lock` for as long as a command writes `path` (a
file or a run directory); a second command on the same output is refused in one line naming the holder
(its pid, host, start time and command line). The kernel releases the lock when its holder exits or
crashes, so a stale lock file never blocks a later run; a finished holder removes the file (while still
holding the lock, and a new holder checks that the file it locked is still the one on disk).
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

from base_suites.runtime.errors import UserInputError


def lock_path(path: str | os.PathLike) -> str:
    return os.path.abspath(os.fspath(path)).rstrip(os.sep) + ".lock"


@contextmanager
def output_lock(path: str | os.PathLike) -> Iterator[None]:
    """Hold the lock of output `path` inside the block; refuse (UserInputError) if another run holds it.
    Creates the output's parent directory."""
    lock = lock_path(path)
    os.makedirs(os.path.dirname(lock), exist_ok=True)
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as exc:
            raise UserInputError(f"{os.fspath(path)}: cannot create its lock file {lock} ({exc.strerror})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise UserInputError(
                f"{os.fspath(path)}: in use by another run ({holder}); wait for it to finish or stop it"
            ) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # the previous holder removed the file after we opened it: lock the new one
    try:
        record = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "started": time.strftime("%Y-%m-%d %H:%M:%S"),
            "command": " ".join(sys.argv),
        }
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(record).encode(), 0)
        yield
    finally:
        try:
            os.remove(lock)
        except OSError:
            pass
        os.close(fd)


def _holder(fd: int) -> str:
    try:
        record = json.loads(os.pread(fd, 4096, 0).decode() or "{}")
        return f"pid {record['pid']} on {record['host']}, started {record['started']}: {record['command']}"
    except (OSError, ValueError, KeyError, TypeError):
        return "holder unknown"
