"""Fixed-length windows over an episode and their labels.

LIBERO-Elegant labels an episode in windows of 25 frames: a window violates a criterion if any step in
it does. The same window arithmetic serves the monitor, the annotated files and human label CSVs.
"""

from __future__ import annotations

import numpy as np


def num_windows(num_steps: int, length: int) -> int:
    return -(-int(num_steps) // int(length))


def window_bounds(num_steps: int, length: int) -> list[tuple[int, int]]:
    """(first frame, last frame) of each window, inclusive."""
    return [(s, min(s + length, num_steps) - 1) for s in range(0, num_steps, length)]


def segment_labels(kept: np.ndarray, length: int) -> np.ndarray:
    """Per-window labels from per-step ones: True where every step of the window kept the criterion."""
    kept = np.asarray(kept, dtype=bool)
    padded = np.ones(num_windows(len(kept), length) * length, dtype=bool)
    padded[: len(kept)] = kept
    return padded.reshape(-1, length).all(axis=1)
