"""Shared fixtures: one thread for torch, and real LIBERO envs built once per module where reused."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "osmesa")
os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")

try:
    import torch

    torch.set_num_threads(1)
except ImportError:  # torch-free test runs still work
    pass


def interrupted_at_second_episode(monkeypatch, collect_call) -> None:
    """Run `collect_call()` with the collector's episode recorder raising KeyboardInterrupt on the second
    episode (a Ctrl-C mid-collection), check it propagates, then restore the recorder."""
    import pytest

    from annotations import collect

    real_record = collect.record_episode
    calls = {"n": 0}

    def crash_on_second(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real_record(*args, **kwargs)

    monkeypatch.setattr(collect, "record_episode", crash_on_second)
    with pytest.raises(KeyboardInterrupt):
        collect_call()
    monkeypatch.setattr(collect, "record_episode", real_record)


def load_benchmark(name: str, folder: str = "benchmarks"):
    """A module under benchmarks/ or another script folder (scripts, not packages: torchrl ships a
    top-level package named `benchmarks` too), imported by path once and cached in sys.modules."""
    import importlib.util
    import sys

    if name not in sys.modules:
        path = os.path.join(os.path.dirname(__file__), os.pardir, folder, f"{name}.py")
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]
