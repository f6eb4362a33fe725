"""Which candidate JITI executes once it re-ranks: the selectors, by name (docs/design.md, JITI).

Candidate 0 is always the base plan. A selector sees every candidate's scores ((members, n): one row per
critic of an ensemble, None without a critic), each candidate's distance from the base plan, and the
run's seeded generator; it returns the index to execute.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from elegant.intervention.config import JITIConfig


def eligible_candidates(distance: np.ndarray, trust_radius: float | None) -> np.ndarray:
    """Which candidates may be chosen: those whose `distance` (`plan_distance` from candidate 0, the base
    plan) is within `trust_radius` (all of them without one)."""
    distance = np.asarray(distance)
    return np.ones(distance.shape, dtype=bool) if trust_radius is None else distance <= trust_radius


def choose_candidate(
    scores: np.ndarray, distance: np.ndarray, trust_radius: float | None, min_gain: float = 0.0
) -> int:
    """Index of the best eligible candidate (`eligible_candidates`), or 0, the base action.

    `scores` is (n,) for one critic or (members, n) for an ensemble (`critics.CriticEnsemble.member_q`).
    A candidate can replace the base action only if every member scores it more than `min_gain` above
    the base action; among those the best mean score wins (the first maximum). So JITI never overrides
    without a reason, and with an ensemble not on one member's say."""
    members = np.atleast_2d(np.asarray(scores, dtype=np.float64))
    agreed = np.all(members - members[:, :1] > min_gain, axis=0) & eligible_candidates(distance, trust_radius)
    if not agreed.any():
        return 0
    return int(np.argmax(np.where(agreed, members.mean(axis=0), -np.inf)))


class Selector(Protocol):
    def select(self, scores: np.ndarray | None, distance: np.ndarray, rng: np.random.Generator) -> int: ...


class CriticArgmax:
    """The critic's best eligible candidate (`choose_candidate`): within the trust radius, beating the base
    plan by more than `min_gain` for every ensemble member; ties and no agreement keep the base plan."""

    def __init__(self, trust_radius: float | None, min_gain: float) -> None:
        self.trust_radius, self.min_gain = trust_radius, min_gain

    def select(self, scores: np.ndarray | None, distance: np.ndarray, rng: np.random.Generator) -> int:
        return choose_candidate(scores, distance, self.trust_radius, self.min_gain)


class RandomEligible:
    """A uniformly random eligible alternative to the base plan (the base plan if none is eligible)."""

    def __init__(self, trust_radius: float | None) -> None:
        self.trust_radius = trust_radius

    def select(self, scores: np.ndarray | None, distance: np.ndarray, rng: np.random.Generator) -> int:
        eligible = np.flatnonzero(eligible_candidates(distance, self.trust_radius)[1:]) + 1
        return int(rng.choice(eligible)) if len(eligible) else 0


SELECTORS = {"critic": CriticArgmax, "random": RandomEligible}


def make_selector(config: JITIConfig) -> Selector:
    """Mode "random" picks at random; every other mode takes the critic's choice."""
    if config.mode == "random":
        return RandomEligible(config.trust_radius)
    return CriticArgmax(config.trust_radius, config.min_gain)
