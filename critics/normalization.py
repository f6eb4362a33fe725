"""Observation and action normalisation, fitted on the training data and saved with the critic.

Observations: the state part of the encoded observation (the task one-hot is left as is) is shifted
and scaled by the dataset's mean and standard deviation, with the scale floored at the dimension's
range / MAX_ABS_Z, so that no training observation lands further than MAX_ABS_Z from 0, and at MIN_STD,
so that jitter of a dimension that hardly moves is not blown up to full scale. States beyond the
training range (a policy knocking over what no demo did) are clipped to +-MAX_ABS_Z. Without the
floors, the transitions where a near-static dimension moves dominated training: a box nudged by 0.03 mm
(std 3e-6 m) or an object's quaternion (std 0.005) turned by a knock became inputs of 10 to 219, and
critics trained on 160 demos of libero_object/0 diverged there (TD loss 0.4 -> 92, Q down to -4900
where every return lies in [-10, 0]).
Actions: mapped affinely from the dataset's per-dimension [low, high] onto [-1, 1], the
box the CQL regulariser samples uniform actions from, so those samples cover the range the data uses.
A dimension whose data range is narrower than 2 * MIN_HALF_RANGE is given that half-range around its
centre, so a constant dimension (e.g. a scripted expert that never rotates) does not divide by zero.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

MIN_STD = 1e-3  # state dims are metres, radians and quaternion components: below a millimetre is jitter
MAX_ABS_Z = 10.0
MIN_HALF_RANGE = 1e-2


def clip_normalised_(z: np.ndarray) -> np.ndarray:
    """Clip normalised states to +-MAX_ABS_Z in place (`Critic.q` calls it every decision: on a few
    dozen values np.clip costs 3x as much as this)."""
    return np.minimum(np.maximum(z, -MAX_ABS_Z, out=z), MAX_ABS_Z, out=z)


@dataclass(frozen=True)
class Normalization:
    """obs_mean/obs_std: (state_dim,) for the state part; action_low/action_high: (action_dim,) raw bounds."""

    obs_mean: np.ndarray
    obs_std: np.ndarray
    action_low: np.ndarray
    action_high: np.ndarray

    @classmethod
    def fit(cls, observations: np.ndarray, actions: np.ndarray, state_dim: int) -> Normalization:
        """Fit on encoded observations (T, state_dim + n_tasks) and raw actions (T, A)."""
        states = np.asarray(observations, dtype=np.float64)[:, :state_dim]
        std = np.maximum(np.maximum(states.std(axis=0), np.ptp(states, axis=0) / MAX_ABS_Z), MIN_STD)
        actions = np.asarray(actions, dtype=np.float64)
        return cls(
            obs_mean=states.mean(axis=0).astype(np.float32),
            obs_std=std.astype(np.float32),
            action_low=actions.min(axis=0).astype(np.float32),
            action_high=actions.max(axis=0).astype(np.float32),
        )

    @property
    def state_dim(self) -> int:
        return int(self.obs_mean.shape[0])

    @property
    def action_center(self) -> np.ndarray:
        return (self.action_low + self.action_high) / 2

    @property
    def action_half_range(self) -> np.ndarray:
        return np.maximum((self.action_high - self.action_low) / 2, MIN_HALF_RANGE).astype(np.float32)

    def observations(self, encoded: np.ndarray) -> np.ndarray:
        """Normalise encoded observations (..., state_dim + n_tasks), clipped to +-MAX_ABS_Z; returns float32."""
        out = np.array(encoded, dtype=np.float32)
        states = out[..., : self.state_dim]
        states -= self.obs_mean
        states /= self.obs_std
        clip_normalised_(states)
        return out

    def actions(self, raw: np.ndarray) -> np.ndarray:
        """Map raw actions (..., A) into [-1, 1] (values outside the data's bounds are clipped to it)."""
        out = (np.asarray(raw, dtype=np.float32) - self.action_center) / self.action_half_range
        return np.clip(out, -1.0, 1.0).astype(np.float32)

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k).tolist() for k in ("obs_mean", "obs_std", "action_low", "action_high")}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Normalization:
        return cls(
            **{k: np.asarray(data[k], dtype=np.float32) for k in ("obs_mean", "obs_std", "action_low", "action_high")}
        )
