"""Import LIBERO's own HDF5 demonstrations (human teleoperation files) into the project's layout.

LIBERO stores, per demo, the flattened MuJoCo `states` and the `actions` (plus images and robot
states). Replaying the stored states in the same task's env gives exactly our low-dimensional
observations, so a user's real demos flow through annotation, critic and policy training unchanged.
"""

from __future__ import annotations

import os
from typing import Any

import h5py
import numpy as np

from annotations.dataset import Demo, DemoWriter, read_attrs
from base_suites import get_task, list_tasks, make_env
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.outputs import check_output
from base_suites.suites import MAIN_SUITES, TaskSpec


def find_task(bddl_file_name: str, suite: str | None = None) -> TaskSpec:
    """The task whose BDDL file has the same name as the one a LIBERO file was recorded with."""
    name = os.path.basename(str(bddl_file_name))
    for candidate in [suite] if suite else list(MAIN_SUITES):
        for task in list_tasks(candidate):
            if os.path.basename(task.bddl_file) == name:
                return task
    raise UserInputError(f"no LIBERO task has BDDL file {name!r}; pass --suite and --task explicitly")


def import_libero_hdf5(
    path: str,
    out: str,
    *,
    suite: str | None = None,
    task: int | None = None,
    overwrite: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """Replay every demo of a LIBERO HDF5 file and write it in this project's layout to `out` (an existing
    `out` only with `overwrite`, replaced once the new file is complete)."""
    from tqdm import tqdm

    check_output(out, "file", overwrite=overwrite, resumable=False)
    if not os.path.exists(path):
        raise UserInputError(f"{path}: no such file")
    try:
        h5 = h5py.File(path, "r")
    except OSError:
        raise UserInputError(f"{path}: not a readable HDF5 file") from None
    with h5:
        if "data" not in h5:
            raise UserInputError(f"{path}: missing group 'data' (expected LIBERO's robomimic layout)")
        attrs = read_attrs(h5["data"])
        if suite is not None and task is not None:
            spec = get_task(suite, task)
        elif "bddl_file_name" in attrs:
            spec = find_task(attrs["bddl_file_name"], suite)
        else:
            raise UserInputError(f"{path}: data has no 'bddl_file_name' attribute; pass --suite and --task")
        names = sorted((n for n in h5["data"] if n.startswith("demo_")), key=lambda n: int(n.split("_")[1]))
        if not names:
            raise UserInputError(f"{path}: no demo_<i> groups under data")
        env = make_env(spec.suite, spec.index, seed=0)
        state_dim = env.get_sim_state().shape[0]
        writer = DemoWriter(
            out,
            {
                "env_args": {
                    "env_name": "libero",
                    "type": 1,
                    "env_kwargs": {"suite": spec.suite, "tasks": [spec.index], "source": os.path.abspath(path)},
                },
                "problem_info": attrs.get("problem_info", {}),
                "language_instruction": spec.language,
                "bddl_file_name": spec.bddl_file,
                "imported_from": "libero",
            },
        )
        successes = []
        try:
            for name in tqdm(names, desc="import", disable=not progress, unit="demo"):
                g = h5["data"][name]
                for key in ("states", "actions"):
                    if key not in g:
                        raise UserInputError(f"{path}: data/{name} has no field '{key}'")
                states, actions = g["states"][()], g["actions"][()]
                if states.shape[1] != state_dim:
                    raise UserInputError(
                        f"{path}: data/{name}/states has {states.shape[1]} values per step, but task "
                        f"{spec.suite}/{spec.index} has {state_dim}"
                    )
                model_xml = g.attrs.get("model_file")
                if isinstance(model_xml, bytes):
                    model_xml = model_xml.decode()
                try:
                    layout = env.fixture_layout_from_xml(model_xml) if model_xml else None
                except UserInputError as e:
                    raise UserInputError(f"{path}: data/{name} attribute 'model_file': {e}") from None
                try:
                    demo = replay_states(env, states, actions, layout)
                except UserInputError as e:
                    raise UserInputError(f"{path}: data/{name}: {e}") from None
                demo.attrs.update(
                    suite=spec.suite,
                    task_index=spec.index,
                    task_name=spec.name,
                    language_instruction=spec.language,
                    init_state_index=0,
                    seed=0,
                    knobs={},
                    expert_version="human:libero",
                    source_demo=name,
                )
                successes.append(demo.attrs["success"])
                writer.append(demo, env.metadata["state_layout"])
            writer.finish()
        except BaseException:
            writer.discard()  # an import is not resumed: a refused or interrupted one leaves nothing
            raise
        finally:
            env.close()
    return {
        "out": out,
        "task": f"{spec.suite}/{spec.index}",
        "demos": len(names),
        "success_rate": float(np.mean(successes)),
    }


def replay_states(env, states: np.ndarray, actions: np.ndarray, layout: dict | None = None) -> Demo:
    """Observations of stored states; the state after the last action comes from stepping it. `layout`
    puts the fixtures where the recording had them (else they stand where a reset puts them)."""
    env.reset(seed=0, options={"init_state": 0})
    if layout:
        env.set_fixture_layout(layout)
    env.set_sim_state(states[0])
    geometry = env.goal_geometry()  # at the first state, as a recording's reset records it
    obs = np.array([env.set_sim_state(s)["state"] for s in states])
    env.set_sim_state(states[-1])
    last_obs, _, _, _, info = env.step(actions[-1])
    next_obs = np.concatenate([obs[1:], last_obs["state"][None]], axis=0)
    rewards = np.zeros(len(actions), dtype=np.float32)
    rewards[-1] = float(info["success"])
    dones = np.zeros(len(actions), dtype=np.uint8)
    dones[-1] = 1
    return Demo(
        name="",
        actions=actions,
        states=states,
        obs=obs,
        next_obs=next_obs,
        rewards=rewards,
        dones=dones,
        attrs={
            "success": bool(info["success"]),
            "perturbation": [],
            "fixture_layout": env.fixture_layout(),
            "goal_geometry": geometry,
        },
    )
