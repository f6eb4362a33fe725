"""Rotation conversions shared by the env and the policy adapters (numpy only, light to import)."""

from __future__ import annotations

import numpy as np


def quat_to_axis_angle(quat: np.ndarray) -> np.ndarray:
    """A robosuite quaternion (x, y, z, w) as an axis-angle vector (axis times angle in radians), as the
    VLA clients of LIBERO convert `robot0_eef_quat`."""
    w = float(np.clip(quat[3], -1.0, 1.0))
    den = np.sqrt(1.0 - w * w)
    return np.zeros(3) if den < 1e-10 else np.asarray(quat[:3], dtype=np.float64) * (2.0 * np.arccos(w) / den)
