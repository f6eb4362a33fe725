"""Human segment labels as CSV: read and validate, apply over the automatic labels, export.

The CSV has one header line and one row per labelled span::

    demo,start_frame,end_frame,criterion,label
    demo_0,25,49,collision,violated
    demo_3,0,24,alignment,1

A span covers whole windows of the annotation's segment length: `start_frame` is the first frame of a
window, `end_frame` (inclusive) the last frame of the same or a later window (the last window of a demo
ends at its last frame). `label` is kept/violated or 1/0. A human label replaces the automatic label of
those windows, and every step in them takes the same value, so the elegance reward agrees with the
windows. Bad rows are refused with the CSV line number ("row N" counts the header as row 1).
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from annotations.dataset import DemoFile
from annotations.format import CRITERIA
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import atomic_write
from itc import EpisodeVerdict, window_bounds

HEADER = ("demo", "start_frame", "end_frame", "criterion", "label")
LABELS = {"kept": True, "1": True, "violated": False, "0": False}


@dataclass(frozen=True)
class HumanLabel:
    """One validated CSV row: a criterion's label for windows first..last of a demo."""

    row: int
    demo: str
    first_window: int
    last_window: int
    criterion: str
    kept: bool


def _frame(path: str, row: int, field: str, text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise UserInputError(f"{path}: row {row}: {field} must be an integer frame index, got {text!r}") from None


def _listing(values: list[int]) -> str:
    return ", ".join(map(str, values)) if len(values) <= 4 else f"{values[0]}, {values[1]}, ..., {values[-1]}"


def _parse_row(
    path: str, row: int, cells: list[str], demo_lengths: Mapping[str, int], segment_length: int
) -> HumanLabel:
    if len(cells) != len(HEADER):
        raise UserInputError(f"{path}: row {row}: expected {len(HEADER)} fields ({','.join(HEADER)}), got {len(cells)}")
    demo, start_text, end_text, criterion, label = (c.strip() for c in cells)
    if demo not in demo_lengths:
        known = ", ".join(list(demo_lengths)[:5]) + (", ..." if len(demo_lengths) > 5 else "")
        raise UserInputError(f"{path}: row {row}: unknown demo {demo!r}; the demo file has: {known}")
    start, end = _frame(path, row, "start_frame", start_text), _frame(path, row, "end_frame", end_text)
    length = demo_lengths[demo]
    bounds = window_bounds(length, segment_length)
    starts, ends = [s for s, _ in bounds], [e for _, e in bounds]
    if start not in starts or end not in ends or end < start:
        raise UserInputError(
            f"{path}: row {row}: window {start}-{end} is out of range for {demo} ({length} frames, windows of "
            f"{segment_length}): start_frame must be a window start ({_listing(starts)}) and end_frame, not before "
            f"it, the inclusive last frame of a window ({_listing(ends)})"
        )
    if criterion not in CRITERIA:
        raise UserInputError(
            f"{path}: row {row}: unknown criterion {criterion!r}; expected one of: {', '.join(CRITERIA)}"
        )
    if label.lower() not in LABELS:
        raise UserInputError(f"{path}: row {row}: unknown label {label!r}; expected one of: kept, violated, 1, 0")
    return HumanLabel(row, demo, starts.index(start), ends.index(end), criterion, LABELS[label.lower()])


def read_human_labels(path: str, demo_lengths: Mapping[str, int], segment_length: int) -> dict[str, list[HumanLabel]]:
    """Validated labels per demo name; `demo_lengths` maps each demo of the labelled file to its length."""
    if not os.path.exists(path):
        raise UserInputError(f"{path}: no such labels file")
    labels: dict[str, list[HumanLabel]] = {}
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.reader(fh)
            header = next(reader, None)
            if header is None or tuple(h.strip().lower() for h in header) != HEADER:
                raise UserInputError(
                    f"{path}: row 1: header must be {','.join(HEADER)}, got {','.join(header or [])!r}"
                )
            for cells in reader:
                if not any(c.strip() for c in cells):
                    continue
                label = _parse_row(path, reader.line_num, cells, demo_lengths, segment_length)
                _refuse_conflict(path, label, labels.get(label.demo, []))
                labels.setdefault(label.demo, []).append(label)
    except UnicodeDecodeError as exc:
        raise UserInputError(f"{path}: not UTF-8 text (byte {exc.start}); save the labels as UTF-8 CSV") from None
    return labels


def _refuse_conflict(path: str, label: HumanLabel, earlier: list[HumanLabel]) -> None:
    """Two rows that label the same window of the same criterion differently: which one holds is not the
    file's order to decide."""
    for other in earlier:
        overlap = label.first_window <= other.last_window and other.first_window <= label.last_window
        if other.criterion == label.criterion and overlap and other.kept != label.kept:
            raise UserInputError(
                f"{path}: rows {other.row} and {label.row} label {label.criterion} of {label.demo} differently "
                "in the same window; keep one"
            )


def apply_human_labels(verdict: EpisodeVerdict, labels: list[HumanLabel]) -> EpisodeVerdict:
    """The verdict with the human labels replacing the automatic ones of their windows."""
    length = verdict.segment_length
    steps = {c: np.array(verdict.steps[c], dtype=bool) for c in CRITERIA}
    segments = {c: np.array(verdict.segments[c], dtype=bool) for c in CRITERIA}
    events = list(verdict.events)
    for label in labels:
        first, last = label.first_window * length, (label.last_window + 1) * length
        steps[label.criterion][first:last] = label.kept
        segments[label.criterion][label.first_window : label.last_window + 1] = label.kept
        word = "kept" if label.kept else "violated"
        frames = f"{first}-{min(last, len(steps[label.criterion])) - 1}"
        events.append((first, label.criterion, f"human label (row {label.row}): {word} in frames {frames}"))
    return EpisodeVerdict(verdict.success, steps, segments, tuple(sorted(events, key=lambda e: e[0])), length)


def export_segment_labels(annotated_path: str, csv_path: str) -> int:
    """Write the segment labels of an annotated file as a human-label CSV (atomically); returns rows written."""
    text = io.StringIO(newline="")
    writer = csv.writer(text)
    writer.writerow(HEADER)
    rows = 0
    with DemoFile(annotated_path, require_labels=True) as demos:
        length = int(demos.attrs["annotation"]["segment_length"])
        for demo in demos:
            for w, (start, end) in enumerate(window_bounds(demo.num_samples, length)):
                for c in CRITERIA:
                    writer.writerow([demo.name, start, end, c, "kept" if demo.itc_segments[c][w] else "violated"])
                    rows += 1
    os.makedirs(os.path.dirname(os.path.abspath(csv_path)), exist_ok=True)
    atomic_write(csv_path, text.getvalue())
    return rows
