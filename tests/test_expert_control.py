"""The expert's servo targets (pure rotation maths, no simulator)."""

import numpy as np

from base_suites.experts.articulated import HANDLE_ROLL, _hand_facing
from base_suites.experts.control import grasp_rotation, pitched_down, rotation_error


def test_pitched_down_points_down_by_a_tilt_alone():
    """A level hand (after a drawer pull) is tilted to pointing down about a horizontal axis: the
    quarter turn, none of it about the vertical, which would turn the wrist."""
    level = _hand_facing(np.array([0.0, -1.0, 0.0]), HANDLE_ROLL + np.pi)
    down = pitched_down(level)
    assert np.allclose(down[:, 2], [0.0, 0.0, -1.0])
    turn = rotation_error(down, level)
    assert np.isclose(np.linalg.norm(turn), np.pi / 2) and abs(turn[2]) < 1e-9
    assert np.allclose(pitched_down(grasp_rotation(0.7)), grasp_rotation(0.7))  # already down: unchanged
