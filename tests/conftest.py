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
