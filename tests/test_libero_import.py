"""Importing LIBERO's own HDF5 demos: replayed states must give the observations a live rollout gave."""

import json

import h5py
import numpy as np
import pytest

from annotations import DemoFile
from annotations.collect import record_episode
from annotations.libero_import import import_libero_hdf5
from base_suites import UserInputError, make_env
from base_suites.experts import ScriptedExpert

pytestmark = pytest.mark.sim


def _write_libero_file(path, env, states, actions, model_xml=None):
    """A file in LIBERO's layout (as its create_dataset script writes them), images included."""
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        data.attrs["bddl_file_name"] = "libero/bddl_files/libero_object/" + env.task.bddl_file.split("/")[-1]
        data.attrs["problem_info"] = json.dumps(
            {"problem_name": "libero_floor_manipulation", "language_instruction": env.task.language}
        )
        data.attrs["env_args"] = json.dumps({"type": 1, "env_name": "Libero_Floor_Manipulation"})
        data.attrs["num_demos"] = 1
        demo = data.create_group("demo_0")
        demo.create_dataset("states", data=states)
        demo.create_dataset("actions", data=actions)
        demo.create_dataset("obs/agentview_rgb", data=np.zeros((len(actions), 8, 8, 3), dtype=np.uint8))
        demo.create_dataset("rewards", data=np.zeros(len(actions)))
        demo.create_dataset("dones", data=np.zeros(len(actions)))
        demo.attrs["num_samples"] = len(actions)
        if model_xml is not None:
            demo.attrs["model_file"] = model_xml


def test_imported_demo_reproduces_live_observations(tmp_path):
    env = make_env("libero_object", 7, seed=0)
    obs, _ = env.reset(options={"init_state": 2})
    expert = ScriptedExpert(env)
    expert.reset(env.metadata, episode=0)
    live = record_episode(env, expert, obs)
    assert live["success"]
    source = tmp_path / "libero_demo.hdf5"
    _write_libero_file(source, env, live["states"], live["actions"])
    summary = import_libero_hdf5(str(source), str(tmp_path / "ours.hdf5"), progress=False)
    assert summary["task"] == "libero_object/7" and summary["success_rate"] == 1.0
    with DemoFile(tmp_path / "ours.hdf5") as f:
        demo = next(iter(f))
    np.testing.assert_allclose(demo.obs, live["obs"], atol=1e-6)
    np.testing.assert_allclose(demo.next_obs[:-1], live["next_obs"][:-1], atol=1e-6)
    assert demo.attrs["expert_version"] == "human:libero" and demo.attrs["success"]


def test_import_places_fixtures_from_the_recorded_model_xml(tmp_path):
    env = make_env("libero_goal", 0, seed=0, settle_steps=0)
    env.reset(seed=5)
    recorded, recorded_goal = env.fixture_layout(), env.goal_geometry()
    states = np.array([env.get_sim_state()] * 3)
    source = tmp_path / "goal.hdf5"
    _write_libero_file(source, env, states, np.zeros((3, 7)), env.domain.sim.model.get_xml())
    import_libero_hdf5(str(source), str(tmp_path / "ours.hdf5"), progress=False)
    with DemoFile(tmp_path / "ours.hdf5") as f:
        imported, imported_goal = (next(iter(f)).attrs[k] for k in ("fixture_layout", "goal_geometry"))
    assert imported.keys() == recorded.keys()
    region = "wooden_cabinet_1_middle_region"  # the goal region stands where the recording's fixture put it
    assert imported_goal["goal"] == recorded_goal["goal"] == [["open", region]]
    np.testing.assert_allclose(
        imported_goal["regions"][region]["position"], recorded_goal["regions"][region]["position"], atol=1e-5
    )
    for name in recorded:
        np.testing.assert_allclose(imported[name], recorded[name], atol=1e-5)


def test_import_refuses_wrong_state_size_and_missing_fields(tmp_path):
    env = make_env("libero_object", 7, seed=0, settle_steps=0)
    path = tmp_path / "bad.hdf5"
    _write_libero_file(path, env, np.zeros((3, 5)), np.zeros((3, 7)))
    with pytest.raises(UserInputError, match="states has 5 values per step"):
        import_libero_hdf5(str(path), str(tmp_path / "o.hdf5"), progress=False)
    assert not list(tmp_path.glob("o.hdf5*"))  # a refused import leaves nothing behind
    with h5py.File(tmp_path / "empty.hdf5", "w") as f:
        f.create_group("nodata")
    with pytest.raises(UserInputError, match="missing group 'data'"):
        import_libero_hdf5(str(tmp_path / "empty.hdf5"), str(tmp_path / "o.hdf5"), progress=False)
