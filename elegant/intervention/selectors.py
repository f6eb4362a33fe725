"""Which candidate JITI executes once it re-ranks: the selectors (docs/design.md, JITI).

Candidate 0 is always the base plan. A selector sees one re-ranked decision (`Choice`): the candidate
plans, their scores ((members, n): one row per critic of an ensemble, None without a critic), each
candidate's distance from the base plan, the run's seeded generator and, on demand, the base policy's
own log-density of each plan; it returns the index to execute. Each mode (`elegant.intervention.modes`)
builds its selector.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np


def eligible_candidates(distance: np.ndarray, trust_radius: float | None) -> np.ndarray:
    """Which candidates may be chosen: those whose `distance` (`plan_distance` from candidate 0, the base
    plan) is within `trust_radius` (all of them without one)."""
    distance = np.asarray(distance)
    return np.ones(distance.shape, dtype=bool) if trust_radius is None else distance <= trust_radius


def choose_candidate(scores: np.ndarray, distance: np.ndarray, trust_radius: float | None, min_gain: float) -> int:
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


@dataclass(slots=True)
class Choice:
    """One re-ranked decision as a selector sees it. `log_prob()` asks the base policy for its log-density
    of each plan (n,), only when a selector needs it (`JITIMode.policy_needs`)."""

    plans: np.ndarray
    scores: np.ndarray | None
    distance: np.ndarray
    rng: np.random.Generator
    log_prob: Callable[[], np.ndarray]


class Selector(Protocol):
    def select(self, choice: Choice) -> int: ...


class CriticArgmax:
    """The critic's best eligible candidate (`choose_candidate`): within the trust radius, beating the base
    plan by more than `min_gain` for every ensemble member; ties and no agreement keep the base plan."""

    def __init__(self, trust_radius: float | None, min_gain: float) -> None:
        self.trust_radius, self.min_gain = trust_radius, min_gain

    def select(self, choice: Choice) -> int:
        return choose_candidate(choice.scores, choice.distance, self.trust_radius, self.min_gain)


class RandomEligible:
    """A uniformly random eligible alternative to the base plan (the base plan if none is eligible)."""

    def __init__(self, trust_radius: float | None) -> None:
        self.trust_radius = trust_radius

    def select(self, choice: Choice) -> int:
        eligible = np.flatnonzero(eligible_candidates(choice.distance, self.trust_radius)[1:]) + 1
        return int(choice.rng.choice(eligible)) if len(eligible) else 0
