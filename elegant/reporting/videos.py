"""The episodes a comparison shows as videos, replayed and written (`elegant report RUNS --out DIR --videos K`).

What a researcher wants to watch first: for every later run paired with the first on their shared starts,
the episodes it made elegant (the first run's episode was not) and those it spoiled, each as one clip of
both runs side by side; and for every run its inelegant successes (the task done, a constraint broken).
Up to K per group and run, in task and episode order. Clips go to OUT/videos/<group>/.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from tqdm import tqdm

from elegant.evaluation.metrics import episode_pairs
from elegant.reporting.replay import annotate, replay_episode, side_by_side, write_video

GROUPS = {
    "made_elegant": "made elegant (not elegant in the first run, elegant here)",
    "spoiled": "spoiled (elegant in the first run, not here)",
    "inelegant_success": "inelegant successes (the task done, a constraint broken)",
}


def choose_clips(runs: Sequence[Sequence[Mapping[str, Any]]], k: int) -> list[dict[str, Any]]:
    """Up to `k` clips per group and run: {"group", "runs" (indices into `runs`), "records" (one per run)}."""
    clips: list[dict[str, Any]] = []
    for i, later in enumerate(runs[1:], 1):
        pairs = episode_pairs(runs[0], later)
        made = [p for p in pairs if not p[0]["elegant"] and p[1]["elegant"]]
        spoiled = [p for p in pairs if p[0]["elegant"] and not p[1]["elegant"]]
        for group, chosen in (("made_elegant", made), ("spoiled", spoiled)):
            clips += [{"group": group, "runs": [0, i], "records": list(p)} for p in chosen[:k]]
    for i, records in enumerate(runs):
        inelegant = [r for r in records if r["success"] and not r["elegant"]]
        clips += [{"group": "inelegant_success", "runs": [i], "records": [r]} for r in inelegant[:k]]
    return clips


def write_clips(
    dirs: Sequence[str | os.PathLike],
    labels: Sequence[str],
    runs: Sequence[Sequence[Mapping[str, Any]]],
    out: str | os.PathLike,
    k: int,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Replay and write the chosen clips; returns each one's group, runs, task, episode and path (relative to
    OUT)."""
    written = []
    for clip in tqdm(choose_clips(runs, k), desc="videos", unit="clip", disable=not progress):
        frames = [
            annotate(replay_episode(dirs[i], record), labels[i]) for i, record in zip(clip["runs"], clip["records"])
        ]
        record = clip["records"][-1]
        names = "_vs_".join(Path(dirs[i]).name or f"run{i}" for i in clip["runs"])
        name = f"{record['task'].replace('/', '_')}_ep{record['episode']}_{names}.mp4"
        path = Path("videos") / clip["group"] / name
        write_video(Path(out) / path, frames[0] if len(frames) == 1 else side_by_side(*frames))
        written.append(
            {
                "group": clip["group"],
                "runs": [labels[i] for i in clip["runs"]],
                "task": record["task"],
                "episode": int(record["episode"]),
                "path": str(path),
            }
        )
    return written


def clips_markdown(clips: Sequence[Mapping[str, Any]]) -> list[str]:
    """The report's section listing the clips by group (empty without clips)."""
    if not clips:
        return []
    lines = ["", "## Episodes to watch", ""]
    for group, title in GROUPS.items():
        chosen = [c for c in clips if c["group"] == group]
        if chosen:
            lines += [f"**{title}**", ""]
            lines += [
                f"- {c['task']} episode {c['episode']}, {' | '.join(c['runs'])}: [{c['path']}]({c['path']})"
                for c in chosen
            ]
            lines.append("")
    return lines
