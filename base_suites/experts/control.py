"""Closed-loop end-effector servoing through LIBERO's OSC_POSE delta action space.

OSC moves slower than its nominal 0.05 m / 0.5 rad per step and leaves a few centimetres of steady
error near the robot base, so targets are tracked on *measured* positions with a proportional term plus
a small integral term, and a move is done only when the measured error is within tolerance.
"""

from __future__ import annotations

import numpy as np

POS_SCALE = 0.05  # metres per unit action (robosuite OSC_POSE output_max)
ROT_SCALE = 0.5  # radians per unit action
OPEN, CLOSE = -1.0, 1.0
# Gripper pointing straight down with its fingers closing along world y: LIBERO's home orientation.
DOWN = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_axis(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def rotation_error(target: np.ndarray, current: np.ndarray) -> np.ndarray:
    """Axis-angle vector (world frame) that rotates `current` onto `target`."""
    r = target @ current.T
    angle = np.arccos(np.clip((np.trace(r) - 1) / 2, -1.0, 1.0))
    if angle < 1e-6:
        return np.zeros(3)
    axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    norm = np.linalg.norm(axis)
    if norm < 1e-9:  # angle near pi: pick the dominant diagonal axis
        axis = np.sqrt(np.clip((np.diag(r) + 1) / 2, 0, None))
        norm = np.linalg.norm(axis)
    return axis / norm * angle


def grasp_rotation(yaw: float, tilt_axis: np.ndarray | None = None, tilt: float = 0.0) -> np.ndarray:
    """Gripper pointing down, fingers closing along world direction (sin(yaw)... see DOWN), optionally tilted."""
    r = rot_z(yaw) @ DOWN
    if tilt and tilt_axis is not None:
        r = rot_axis(tilt_axis, tilt) @ r
    return r


def pitched_down(current: np.ndarray) -> np.ndarray:
    """`current` tilted the short way to pointing straight down, the turn about the hand's own axis
    (its last joint) left as it is."""
    pointing = current[:, 2]
    axis = np.cross(pointing, [0.0, 0.0, -1.0])
    if np.linalg.norm(axis) < 1e-9:
        return current if pointing[2] < 0 else rot_axis([1.0, 0.0, 0.0], np.pi) @ current
    return rot_axis(axis, float(np.arccos(np.clip(-pointing[2], -1.0, 1.0)))) @ current


WRIST_LIMIT = 2.6  # rad: keep the Panda's last joint (limit 2.90) clear of its stop


def nearest_grasp_rotation(
    yaw: float, current: np.ndarray, wrist: float, then: float = 0.0, swing: float = 0.0, shortest: bool = False
) -> np.ndarray:
    """`grasp_rotation(yaw)`, or the same grasp with the hand turned half a turn (a parallel gripper is
    symmetric) when only that keeps the last joint (now at `wrist`) off its stop, also after a planned
    further turn of `then` rad about world z (a knob turn). With the hand pointing down a turn of d about
    world z moves that joint by about -d, and the arm swinging by `swing` rad about the robot base on the
    way there (its first joint turning) moves it by about +swing; a joint at its stop makes OSC drag the
    hand sideways instead of turning it. The plain grasp stays the default so demonstrations keep one
    hand orientation per grasp (a policy cloned from them would otherwise have to learn both). With
    `shortest`, the one the hand turns to the short way is preferred instead: a drawer pushed shut with
    the hand pitched after a 150 deg turn about the vertical sent OSC through the wrist's pitch stop."""
    options = []
    for flipped, candidate in enumerate((grasp_rotation(yaw), grasp_rotation(yaw + np.pi))):
        turn = float(rotation_error(candidate, current)[2])
        arrived = wrist - turn + swing
        blocked = max(abs(arrived), abs(arrived - then)) > WRIST_LIMIT
        options.append((blocked, abs(turn) if shortest else flipped, candidate))
    return min(options, key=lambda o: o[:2])[2]


def finger_axis(yaw: float) -> np.ndarray:
    """World direction along which the fingers close for a given grasp yaw."""
    return rot_z(yaw) @ np.array([0.0, 1.0, 0.0])


class Servo:
    """Turns a target pose into one OSC_POSE action from the measured pose (PI on position, P on rotation)."""

    def __init__(
        self, gain: float = 1.6, integral_gain: float = 0.08, rot_gain: float = 1.2, max_speed: float = 1.0
    ) -> None:
        self.gain, self.integral_gain, self.rot_gain, self.max_speed = gain, integral_gain, rot_gain, max_speed
        self._integral = np.zeros(3)

    def reset_integral(self) -> None:
        self._integral = np.zeros(3)

    def action(
        self, pos_err: np.ndarray, rot_err: np.ndarray, gripper: float, speed: float | None = None
    ) -> np.ndarray:
        limit = self.max_speed if speed is None else speed
        self._integral = np.clip(self._integral + pos_err / POS_SCALE, -8, 8)
        move = self.gain * pos_err / POS_SCALE + self.integral_gain * self._integral
        norm = np.linalg.norm(move)
        if norm > limit:
            move = move * (limit / norm)
        turn = np.clip(self.rot_gain * rot_err / ROT_SCALE, -1.0, 1.0)
        return np.concatenate([move, turn, [gripper]])
