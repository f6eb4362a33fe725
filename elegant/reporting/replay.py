"""Eval episodes replayed from their records, rendered and written as MP4s (`elegant report --videos K`).

An episode is a function of its task, start, reset seed and actions (docs/design.md §3.5), so the runner
keeps in each episode's trace the executed actions and a digest of the final simulator state
(`replay_record`). `replay_episode` rebuilds the env as the run did (suite, task, seed, horizon,
perturbation), resets it to the recorded start, steps the recorded actions with rendering on, and checks
that it ends in the recorded simulator state: a replay that diverged raises rather than show another
episode. `annotate` marks each frame with the run's label, the step, the criteria whose 25-step window is
violated there (a red border) and JITI's overrides; `write_video` writes the frames with imageio's ffmpeg.
"""

from __future__ import annotations

import base64
import hashlib
import io
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from annotations.format import SEGMENT_LENGTH
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import atomic_write, read_json_file

VIDEO_FPS = 20  # LIBERO's control rate: a clip plays in real time
FRAME_SIZE = 256  # rendered side in pixels


def _digest(state: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(state, dtype=np.float64).tobytes()).hexdigest()


def replay_record(actions: np.ndarray, final_sim_state: np.ndarray) -> dict[str, Any]:
    """What an episode's trace keeps to replay it: the (T, 7) actions as float64 bytes (exact), and the
    SHA-256 of the final MuJoCo state (time, qpos, qvel) to check the replay against."""
    actions = np.ascontiguousarray(actions, dtype=np.float64)
    return {
        "actions": base64.b64encode(actions.tobytes()).decode("ascii"),
        "steps": int(actions.shape[0]),
        "final_state_sha256": _digest(final_sim_state),
    }


def recorded_actions(replay: Mapping[str, Any]) -> np.ndarray:
    return np.frombuffer(base64.b64decode(replay["actions"]), dtype=np.float64).reshape(int(replay["steps"]), 7)


@dataclass
class Replay:
    """A replayed episode: frames (the start, then one per step, (H, W, 3) uint8), its trace and record."""

    frames: list[np.ndarray]
    trace: dict[str, Any]
    record: dict[str, Any]


def replay_episode(run_dir: str | os.PathLike, record: Mapping[str, Any], size: int = FRAME_SIZE) -> Replay:
    """Replay one episode of an eval run (a line of its episodes.jsonl) with rendering on."""
    from base_suites import make_env
    from base_suites.env import CAMERA

    run_dir = Path(run_dir)
    config = read_json_file(run_dir / "config.json", "run config")
    trace_path = run_dir / record["trace"]
    trace = read_json_file(trace_path, "episode trace")
    if "replay" not in trace:
        raise UserInputError(f"{trace_path}: recorded before episodes kept their actions; rerun it to watch it")
    actions = recorded_actions(trace["replay"])
    env = make_env(
        config["suite"],
        record["task_index"],
        seed=config["seed"],
        obs="rgb",
        camera_size=size,
        max_steps=config["max_steps"],
        perturbation=config["perturbation"],
    )
    try:
        obs, _ = env.reset(seed=record["seed"], options={"init_state": record["init_index"]})
        frames = [obs[CAMERA]]
        for action in actions:
            obs, *_ = env.step(action)
            frames.append(obs[CAMERA])
        final = env.get_sim_state()
    finally:
        env.close()
    if _digest(final) != trace["replay"]["final_state_sha256"]:
        raise RuntimeError(
            f"{trace_path}: the replay ended in another simulator state than the episode did; the env is not "
            "deterministic here (another MuJoCo build or CPU?)"
        )
    return Replay(frames, trace, dict(record))


def _violated_at(trace: Mapping[str, Any], step: int) -> list[str]:
    window = step // SEGMENT_LENGTH
    return [c for c, kept in trace.get("segments", {}).items() if window < len(kept) and not kept[window]]


def annotate(replay: Replay, label: str) -> list[np.ndarray]:
    """Frames with a caption (label, step, outcome) and, where a criterion's window is violated, a red
    border and the criteria's names; frames where JITI overrode the policy say so."""
    from PIL import Image, ImageDraw, ImageFont

    font = ImageFont.load_default(size=11)

    decisions = replay.trace.get("decisions", {})
    overridden = {int(s) for s, hit in zip(decisions.get("step", []), decisions.get("intervened", [])) if hit}
    outcome = ("success" if replay.record["success"] else "failure") + (", elegant" if replay.record["elegant"] else "")
    out = []
    for step, frame in enumerate(replay.frames):
        image = Image.fromarray(np.asarray(frame, dtype=np.uint8))
        draw = ImageDraw.Draw(image)
        width, height = image.size
        draw.rectangle([0, 0, width, 14], fill=(0, 0, 0))
        draw.text((3, 1), f"{label}  step {step}  {outcome}", fill=(255, 255, 255), font=font)
        violated = _violated_at(replay.trace, max(step - 1, 0))
        if violated:
            draw.rectangle([0, 0, width - 1, height - 1], outline=(230, 30, 30), width=4)
            draw.rectangle([0, height - 14, width, height], fill=(120, 0, 0))
            draw.text((3, height - 13), "violated: " + ", ".join(violated), fill=(255, 255, 255), font=font)
        if step - 1 in overridden:
            draw.text((3, 16), "JITI override", fill=(255, 230, 0), font=font)
        out.append(np.asarray(image))
    return out


def side_by_side(left: Sequence[np.ndarray], right: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Two clips of one start, next to each other; the shorter holds its last frame."""
    n = max(len(left), len(right))
    return [np.hstack([left[min(i, len(left) - 1)], right[min(i, len(right) - 1)]]) for i in range(n)]


def write_video(path: str | os.PathLike, frames: Sequence[np.ndarray], fps: int = VIDEO_FPS) -> Path:
    """An H.264 MP4 of the frames, encoded in memory and written whole (`atomic_write`)."""
    import imageio.v2 as imageio

    buffer = io.BytesIO()
    imageio.mimwrite(buffer, list(frames), format="mp4", fps=fps, codec="libx264", macro_block_size=8)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, buffer.getvalue())
    return path
