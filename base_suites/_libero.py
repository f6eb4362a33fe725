"""The single place that imports LIBERO and robosuite.

Rendering backends are chosen from environment variables when robosuite is first imported, so the
headless defaults are set here before that import: EGL where an NVIDIA GPU is present (rendering on the
GPU), else OSMesa (software, works without a display or GPU; EGL finds no device there). `MUJOCO_GL`
set by the user wins.
Keeping the import lazy also keeps `elegant --help` instant.
"""

from __future__ import annotations

import contextlib
import functools
import io
import logging
import os
from types import ModuleType


def rendering_backend() -> str:
    """The GL backend MuJoCo renders with in this process (`MUJOCO_GL`, else the headless default)."""
    return os.environ.get("MUJOCO_GL") or ("egl" if os.path.exists("/dev/nvidiactl") else "osmesa")


def _configure_headless_rendering() -> None:
    os.environ.setdefault("MUJOCO_GL", rendering_backend())
    os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])


@functools.cache
def libero_modules() -> dict[str, ModuleType]:
    """Import LIBERO's benchmark and env-wrapper modules once, quietly."""
    _configure_headless_rendering()
    logging.getLogger("robosuite_logs").setLevel(logging.ERROR)
    with contextlib.redirect_stdout(io.StringIO()):
        import robosuite  # noqa: F401  (prints macro warnings on first import)
        from libero.libero import benchmark, get_libero_path
        from libero.libero.envs import env_wrapper
        from libero.libero.envs.bddl_utils import get_problem_info
    logging.getLogger("robosuite_logs").setLevel(logging.ERROR)
    return {
        "benchmark": benchmark,
        "env_wrapper": env_wrapper,
        "get_libero_path": get_libero_path,
        "get_problem_info": get_problem_info,
    }


def quietly(fn, *args, **kwargs):
    """Call a LIBERO function that prints progress chatter to stdout, discarding the chatter."""
    with contextlib.redirect_stdout(io.StringIO()):
        return fn(*args, **kwargs)
