"""Annotate a demo file with ITC labels by replaying its stored simulator states.

For each demo the task's env is reset to the demo's init state, its fixtures are put where the recording
had them (`fixture_layout`: the stored states do not hold it), then jumped to each stored MuJoCo state
in turn and the ITC monitor judges every transition (s_t, a_t, s_t+1). The state after the last action
is the recorded `final_state`, and whether the episode succeeded is its recorded last reward, LIBERO's
verdict when it ran (the goal's contacts, found afresh after a jump to that state, can miss an object
that touched down at speed); a file without one (LIBERO's own) gets it by stepping the env once from
the last stored state, which is only approximate: the controller's internal state (the gripper's
smoothed command, the OSC target) is not part of a MuJoCo state, and that last transition is where
LIBERO ends a successful episode, so where placements are judged. No policy or expert runs, so the
same labelling works for our scripted demos and for imported LIBERO demos. The annotated copy (layout
in `annotations.format`) adds per-step and per-window labels, the elegance reward and its discounted
return-to-go; human labels from a CSV replace automatic windows.
"""

from __future__ import annotations

import json
import os
from collections import OrderedDict
from functools import partial
from typing import Any

import numpy as np
from tqdm import tqdm

from annotations.dataset import Demo, DemoFile, DemoWriter
from annotations.format import ANNOTATION_SCHEMA_VERSION, CRITERIA
from annotations.human_labels import apply_human_labels, read_human_labels
from base_suites import LiberoEnv, UserInputError, make_env, make_perturbation
from base_suites.runtime.jobs import Workers, check_workers, in_order, run_jobs
from base_suites.runtime.outputs import check_output
from itc import EpisodeVerdict, ITCMonitor, ITCParams, derive_spec


def discounted_return_to_go(rewards: np.ndarray, gamma: float) -> np.ndarray:
    """G_t = r_t + gamma * G_t+1 within one episode (the Monte-Carlo return Cal-QL clips with)."""
    out = np.zeros(len(rewards), dtype=np.float64)
    running = 0.0
    for t in range(len(rewards) - 1, -1, -1):
        running = float(rewards[t]) + gamma * running
        out[t] = running
    return out.astype(np.float32)


def start_replay(env: LiberoEnv, demo: Demo) -> None:
    """Put `env` where the demo started: its init state and reset seed, its fixtures, its first stored state."""
    init = demo.attrs.get("init_state_index")
    valid_init = isinstance(init, (int, np.integer)) and 0 <= int(init) < env.task.n_init_states
    # The recorded reset seed rebuilds the recorded scene (fixtures, perturbation placements) where the
    # file predates `fixture_layout`; without one, seed 0 at least makes the replay the same every time.
    env.reset(seed=int(demo.attrs.get("reset_seed", 0)), options={"init_state": int(init) if valid_init else 0})
    if demo.attrs.get("fixture_layout"):
        try:
            env.set_fixture_layout(demo.attrs["fixture_layout"])
        except UserInputError as e:
            raise UserInputError(f"data/{demo.name} attribute 'fixture_layout': {e}") from None
    env.set_sim_state(demo.states[0])


def replay_verdict(env: LiberoEnv, monitor: ITCMonitor, demo: Demo) -> EpisodeVerdict:
    """ITC labels of one demo from its stored states (see module docstring)."""
    start_replay(env, demo)
    monitor.reset()
    success = goal_reached = False
    for t in range(demo.num_samples):
        if t + 1 < demo.num_samples:
            env.set_sim_state(demo.states[t + 1])
        elif demo.final_state is not None:
            env.set_sim_state(demo.final_state)
            # the recorded reward is LIBERO's own verdict when the episode ran (see ITCMonitor.step's goal_reached)
            success = goal_reached = bool(demo.rewards[-1] > 0)
        else:
            env.set_sim_state(demo.states[-1])
            success = bool(env.step(demo.actions[-1])[4]["success"])
        monitor.step(demo.actions[t], goal_reached=goal_reached)
    return monitor.verdict(success)


class _EnvPool:
    """A few envs with their monitors, keyed by task and perturbation (building one takes seconds)."""

    def __init__(self, params: ITCParams, overrides_dir: str | None, path: str, capacity: int = 2) -> None:
        self.params, self.overrides_dir, self.path, self.capacity = params, overrides_dir, path, capacity
        self._open: OrderedDict[str, tuple[LiberoEnv, ITCMonitor]] = OrderedDict()

    def get(self, demo: Demo) -> tuple[LiberoEnv, ITCMonitor]:
        for key in ("suite", "task_index"):
            if key not in demo.attrs:
                raise UserInputError(
                    f"{self.path}: data/{demo.name} has no attribute {key!r} (needed to rebuild its task)"
                )
        records = demo.attrs.get("perturbation") or []
        key = json.dumps([demo.attrs["suite"], int(demo.attrs["task_index"]), records], sort_keys=True)
        if key not in self._open:
            perturbations = [make_perturbation(r["axis"], int(r.get("seed", 0)), r.get("mode")) for r in records]
            env = make_env(
                demo.attrs["suite"], int(demo.attrs["task_index"]), perturbation=perturbations, settle_steps=0
            )
            self._open[key] = (env, ITCMonitor(env, derive_spec(env, self.overrides_dir), self.params))
            while len(self._open) > self.capacity:
                self._open.popitem(last=False)[1][0].close()
        self._open.move_to_end(key)
        env, monitor = self._open[key]
        width = len(env.get_sim_state())
        if demo.states.ndim != 2 or demo.states.shape[1] != width or demo.num_samples == 0:
            raise UserInputError(
                f"{self.path}: data/{demo.name}/states has shape {demo.states.shape}; expected (T>0, {width}), "
                f"the MuJoCo state size of task {demo.task_key}"
            )
        return env, monitor

    def close(self) -> None:
        for env, _ in self._open.values():
            env.close()
        self._open.clear()


class _Replayer:
    """Replays demos of one file by (position, name) and returns their ITC verdicts; its own read handle
    and env pool, so it can run in a worker process."""

    def __init__(self, params: ITCParams, overrides_dir: str | None, path: str) -> None:
        self.path = path
        self.source = DemoFile(path)
        self.pool = _EnvPool(params, overrides_dir, path)

    def __call__(self, job: tuple[int, str]) -> tuple[EpisodeVerdict, dict]:
        """The demo's verdict and its goal geometry (recorded by collection; found at its start for files
        from before, where the replay stands at the demo's first state)."""
        demo = self.source.demo(job[1])
        env, monitor = self.pool.get(demo)
        try:
            geometry = demo.attrs.get("goal_geometry")
            if not geometry:
                start_replay(env, demo)
                geometry = env.goal_geometry()
            return replay_verdict(env, monitor, demo), geometry
        except UserInputError as e:
            raise UserInputError(f"{self.path}: {e}") from None

    def close(self) -> None:
        self.pool.close()
        self.source.close()


def _labelled(demo: Demo, verdict: EpisodeVerdict, geometry: dict, gamma: float) -> Demo:
    reward = verdict.elegance_reward
    attrs = {k: v for k, v in demo.attrs.items() if k != "num_samples"}
    attrs.update(success=verdict.success, elegant=verdict.elegant, violated=verdict.violated, goal_geometry=geometry)
    return Demo(
        name=demo.name,
        actions=demo.actions,
        states=demo.states,
        obs=demo.obs,
        next_obs=demo.next_obs,
        rewards=demo.rewards,
        dones=demo.dones,
        attrs=attrs,
        final_state=demo.final_state,
        itc={c: verdict.steps[c] for c in CRITERIA},
        itc_segments={c: verdict.segments[c] for c in CRITERIA},
        elegance_reward=reward,
        mc_return=discounted_return_to_go(reward, gamma),
    )


def _summary(records: list[dict[str, Any]], in_path: str, out_path: str, human_rows: int) -> dict[str, Any]:
    n = len(records)

    def rate(pred) -> float:
        return round(sum(1 for r in records if pred(r)) / n, 4) if n else 0.0

    return {
        "in_path": in_path,
        "out_path": out_path,
        "demos": n,
        "success_rate": rate(lambda r: r["success"]),
        "elegant_rate": rate(lambda r: r["elegant"]),
        "violation_rate": {c: rate(lambda r, c=c: c in r["violated"]) for c in CRITERIA},
        "human_label_rows": human_rows,
    }


def _done_records(writer: DemoWriter, annotation: dict[str, Any]) -> list[dict[str, Any]]:
    """Verdict attributes of the demos a resumed run already wrote (refused if labelled differently)."""
    before = writer.attrs.get("annotation", {})
    for key in ("gamma", "segment_length", "itc_params", "spec_overrides_dir", "human_labels"):
        if before.get(key) != annotation[key]:
            raise UserInputError(
                f"{writer.partial}: annotation.{key} of the interrupted run differs from this run's; "
                "resume with the same settings or delete the partial folder"
            )
    return [{k: attrs[k] for k in ("success", "elegant", "violated")} for attrs in writer.written_attrs()]


def annotate_file(
    in_path: str,
    out_path: str,
    *,
    labels_csv: str | None = None,
    params: ITCParams | None = None,
    overrides_dir: str | None = None,
    gamma: float = 0.99,
    progress: bool = True,
    resume: bool = False,
    overwrite: bool = False,
    workers: int | Workers = 1,
) -> dict[str, Any]:
    """Write an ITC-annotated copy of a demo file; returns a summary (rates of success, elegance, violations).
    `workers`: processes replaying demos side by side (`base_suites.runtime.jobs`); the file does not depend on it.
    `resume` continues an interrupted annotation (a finished one is summarised as it is); `overwrite`
    replaces an existing file once the new one is complete."""
    check_output(out_path, "file", resume=resume, overwrite=overwrite)
    params = params or ITCParams()
    check_workers(workers)
    if not 0.0 < gamma <= 1.0:
        raise UserInputError(f"gamma must be in (0, 1], got {gamma}")
    if os.path.abspath(in_path) == os.path.abspath(out_path):
        raise UserInputError(f"{out_path}: the annotated file must not replace its input")
    with DemoFile(in_path) as source:
        source.validate()
        human = {}
        if labels_csv:
            human = read_human_labels(labels_csv, {d.name: d.num_samples for d in source}, params.segment_length)
        file_attrs = {k: v for k, v in source.attrs.items() if k not in ("format_version", "total", "annotation")}
        file_attrs["annotation"] = {
            "schema_version": ANNOTATION_SCHEMA_VERSION,
            "gamma": gamma,
            "segment_length": params.segment_length,
            "itc_params": params.to_dict(),
            "criteria": list(CRITERIA),
            "spec_overrides_dir": overrides_dir,
            "human_labels": {"file": labels_csv, "rows": sum(len(v) for v in human.values())} if labels_csv else None,
        }
        writer = DemoWriter(out_path, file_attrs, resume=resume)
        try:
            records = _done_records(writer, file_attrs["annotation"])
            done_before = writer.count
            jobs = list(enumerate(source.names))[done_before:]
            replayer = partial(_Replayer, params, overrides_dir, in_path)
            with run_jobs(replayer, jobs, workers) as results:
                ordered = in_order(results, lambda job: job[0], first=done_before)
                for (_, name), (verdict, geometry) in tqdm(
                    ordered, total=len(jobs), desc="annotate", unit="demo", disable=not progress
                ):
                    verdict = apply_human_labels(verdict, human.get(name, []))
                    writer.append(_labelled(source.demo(name), verdict, geometry, gamma))
                    records.append(
                        {"success": verdict.success, "elegant": verdict.elegant, "violated": verdict.violated}
                    )
            writer.finish()
        except BaseException:
            writer.abandon()
            raise
    return _summary(records, in_path, out_path, sum(len(v) for v in human.values()))
