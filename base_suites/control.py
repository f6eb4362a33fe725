"""One LIBERO control step, two ways: robosuite's own, and a fast path with the same MuJoCo states.

robosuite runs each of LIBERO's 25 physics substeps per control step (500 Hz physics, 20 Hz control) as
`sim.forward()`, the robot controllers (`_pre_action`, whose controller update calls `sim.forward()`
again), `sim.step()` and an update of every observable, and looks its limits and ids up by name. From
MuJoCo 3.3.6 on, `mj_forward` computes nothing `mj_step` does not compute again and leaves the solver's
warm start alone (only the integration writes it), so the fast path runs each substep as
`mujoco.mj_step1` (positions, velocities, the mass matrix and bias forces the controller reads), the arm
control of `base_suites.arm_control` (robosuite's OSC_POSE and gripper arithmetic, compiled, in the same
order), and `mujoco.mj_step2` (actuation, constraints, integration): one kinematics pass per substep and
the same torques, bit for bit. Earlier releases store each `mj_forward`'s solution as the next warm
start, so there the fast path makes robosuite's forwards too (`_forward_writes_warmstart`). Observables
are not updated (the env reads the simulator directly and renders only when an observation mode asks),
nor are robosuite's proprioceptive history buffers (`robot.recent_qpos` and the like, read only by its
Wipe task); the goal is checked once per control step after LIBERO's object-state bookkeeping, as its own
step returns it.

`PHYSICS` names the two: "fast" (the default) and "robosuite" (kept selectable, so the parity tests
and the throughput benchmark can run both).
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Any, Literal, get_args

if TYPE_CHECKING:
    from base_suites.arm_control import ArmControl

Physics = Literal["fast", "robosuite"]
PHYSICS: tuple[str, ...] = get_args(Physics)


@functools.cache
def _forward_writes_warmstart(mujoco: Any) -> bool:
    """Whether this MuJoCo release's `mj_forward` stores its solution as the solver's next warm start (2.3.7
    up to 3.3.5 do; from 3.3.6 only the integration does), asked of the release itself on a falling box.
    Where it does, robosuite's forwards (its step loop's, and each controller update's) steer the
    constraint solver, and the fast path makes the same calls before `mj_step1` (measured: with their
    acceleration stage alone, or with them after `mj_step1`, the states part by 1e-15), keeping only
    the saving of robosuite's Python."""
    model = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><freejoint/><geom size='.1'/></body></worldbody></mujoco>"
    )
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return bool(data.qacc_warmstart.any())


class FastControl:
    """The fast path's control step for one LIBERO env; holds each robot's `ArmControl`, rebuilt whenever
    robosuite replaces a controller (it makes new ones on reset)."""

    def __init__(self) -> None:
        self._arms: list[ArmControl] = []

    def step(self, domain: Any, action: Any) -> bool:
        """One control step of LIBERO's robosuite env `domain` with `action`, leaving the simulator where
        `domain.step(action)` would; returns whether the task's goal holds afterwards."""
        import mujoco  # here, not at import: building the CLI's options must not load the simulator

        if domain.done:
            raise ValueError("executing action in terminated episode")
        domain.timestep += 1
        model, data = domain.sim.model._model, domain.sim.data._data
        arms = self._arms_of(domain, model)
        replay_forwards = _forward_writes_warmstart(mujoco)
        for substep in range(int(domain.control_timestep / domain.model_timestep)):
            if replay_forwards:  # robosuite's step loop calls sim.forward(), and so does a controller's update
                mujoco.mj_forward(model, data)
                for arm in arms:
                    if arm.controller.new_update:  # false on the first substep after a reset updated it
                        mujoco.mj_forward(model, data)
            mujoco.mj_step1(model, data)
            if substep == 0:  # robosuite's policy step
                cutoff = 0
                for arm in arms:
                    arm.set_action(action[cutoff : cutoff + arm.action_dim], data)
                    cutoff += arm.action_dim
            for arm in arms:
                arm.apply(data)
            mujoco.mj_step2(model, data)
        domain.cur_time += domain.control_timestep
        # robosuite's _post_action ends an episode at its horizon; LIBERO's then updates tracked object states
        domain.done = (domain.timestep >= domain.horizon) and not domain.ignore_done
        domain._post_process()
        return bool(domain._check_success())

    def _arms_of(self, domain: Any, model: Any) -> list[ArmControl]:
        from base_suites.arm_control import ArmControl

        if len(self._arms) != len(domain.robots) or any(
            arm.controller is not robot.controller for arm, robot in zip(self._arms, domain.robots)
        ):
            self._arms = [ArmControl(robot, model) for robot in domain.robots]
        return self._arms
