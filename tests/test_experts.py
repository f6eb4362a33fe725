"""Scripted experts and demo collection on the real simulator (one task per primitive family)."""
import h5py
import numpy as np
import pytest

import annotations.collect as collect
from annotations import DemoFile
from base_suites import make_env
from base_suites.experts import ScriptedExpert

pytestmark = pytest.mark.sim


def _solve(suite, task, init=0, quality="clean", episode=0):
    env = make_env(suite, task, seed=0)
    obs, _ = env.reset(options={"init_state": init})
    expert = ScriptedExpert(env, quality=quality, seed=0)
    expert.reset(env.metadata, episode=episode)
    info = {"success": False}
    for _ in range(env.max_steps):
        obs, _, terminated, truncated, info = env.step(expert(obs))
        if terminated or truncated:
            break
    env.close()
    return info["success"], expert


@pytest.mark.parametrize("suite, task, family", [
    ("libero_goal", 0, "open drawer"),
    ("libero_goal", 7, "turn knob"),
    ("libero_spatial", 0, "pick and place (rim grasp of a bowl)"),
])
def test_expert_solves_one_task_per_primitive_family(suite, task, family):
    success, _ = _solve(suite, task)
    assert success, family


def test_drop_knob_releases_from_height_and_is_recorded():
    success, expert = _solve("libero_object", 3, quality={"drop": 1.0})
    assert expert.knobs["drop"] and "drop" in expert.events


def _collect(tmp_path, name, **kw):
    out = str(tmp_path / name)
    summary = collect.collect_demos("libero_object", [0], 2, out, quality={"tilt": 0.5}, seed=4, progress=False, **kw)
    return out, summary


def test_demos_file_layout_and_interrupted_resume_matches_uninterrupted(tmp_path, monkeypatch):
    full, summary = _collect(tmp_path, "full.hdf5")
    assert summary["demos"] == 2 and summary["success_rate"] == 1.0
    with h5py.File(full) as f:
        data = f["data"]
        assert data.attrs["format_version"] == "libero-elegant/1"
        assert "env_args" in data.attrs and "problem_info" in data.attrs and "language_instruction" in data.attrs
        demo = data["demo_0"]
        t = demo["actions"].shape[0]
        assert demo["states"].shape[0] == t and demo["obs/state"].shape[0] == t and demo["next_obs/state"].shape[0] == t
        assert demo["rewards"][-1] == 1.0 and demo["dones"][-1] == 1
        assert {"knobs", "expert_version", "init_state_index"} <= set(demo.attrs)
    real_record = collect.record_episode
    calls = {"n": 0}

    def crash_on_second(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real_record(*args, **kwargs)

    monkeypatch.setattr(collect, "record_episode", crash_on_second)
    with pytest.raises(KeyboardInterrupt):
        _collect(tmp_path, "resumed.hdf5")
    assert (tmp_path / "resumed.hdf5.partial").exists() and not (tmp_path / "resumed.hdf5").exists()
    monkeypatch.setattr(collect, "record_episode", real_record)
    resumed, _ = _collect(tmp_path, "resumed.hdf5", resume=True)
    with DemoFile(full) as a, DemoFile(resumed) as b:
        assert len(a) == len(b) == 2
        for da, db in zip(a, b):
            assert np.array_equal(da.actions, db.actions) and np.array_equal(da.obs, db.obs)
            assert da.attrs["knobs"] == db.attrs["knobs"]
