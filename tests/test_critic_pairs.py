"""Clean-vs-knob continuation pairs: scoring hand-made pairs with a stand-in critic, the input refusals,
and branching real expert rollouts in the simulator."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import load_benchmark

from base_suites.runtime.errors import UserInputError

_pairs = load_benchmark("continuation_pairs")
Continuation, Pair, continuation_pairs, pair_preference = (
    _pairs.Continuation,
    _pairs.Pair,
    _pairs.continuation_pairs,
    _pairs.pair_preference,
)

STATE_SIZE = 3


class SumCritic:
    """Stand-in critic: Q(s, a) = sum of the action, so a side's score is set by the actions we give it."""

    def q(self, state: np.ndarray, actions: np.ndarray) -> np.ndarray:
        assert state.shape == (len(actions), STATE_SIZE) and actions.shape[1:] == (1, 7)
        return actions.sum(-1)


def side(value: float, steps: int = 4) -> Continuation:
    return Continuation(np.zeros((steps, STATE_SIZE)), np.full((steps, 7), value / 7))


def pair(knob: str, clean: float, knobbed: float) -> Pair:
    return Pair("libero_object/0", 0, knob, 5, side(clean), side(knobbed, steps=2))


def test_preference_counts_strict_clean_wins_per_knob():
    pairs = [
        pair("drop", 1.0, 0.0),
        pair("drop", 1.0, 0.5),
        pair("drop", 0.0, 1.0),
        pair("tilt", 2.0, 1.0),
        pair("tilt", 1.0, 1.0),
    ]  # the last one is a tie: no win
    report = pair_preference(SumCritic(), pairs)
    assert (report["pairs"], report["clean_wins"]) == (5, 3)
    assert report["clean_preferred"] == pytest.approx(0.6)
    assert report["mean_gap"] == pytest.approx((1.0 + 0.5 - 1.0 + 1.0 + 0.0) / 5)
    assert report["per_knob"]["drop"] == pytest.approx(
        {"pairs": 3, "clean_wins": 2, "clean_preferred": 2 / 3, "mean_gap": 0.5 / 3}
    )
    assert report["per_knob"]["tilt"] == pytest.approx(
        {"pairs": 2, "clean_wins": 1, "clean_preferred": 0.5, "mean_gap": 0.5}
    )


def test_sides_are_scored_over_the_same_number_of_steps():
    # The clean side runs longer and its later steps score high (states near a successful end): only
    # the first two steps, the length of the knob side, may count.
    clean = Continuation(np.zeros((4, STATE_SIZE)), np.array([[0.0] * 7] * 2 + [[1.0] * 7] * 2))
    report = pair_preference(SumCritic(), [Pair("libero_object/0", 0, "drop", 5, clean, side(0.5, steps=2))])
    assert report["clean_wins"] == 0 and report["mean_gap"] == pytest.approx(-0.5)


def test_preference_without_pairs_has_no_fraction():
    assert pair_preference(SumCritic(), []) == {
        "pairs": 0,
        "clean_wins": 0,
        "clean_preferred": None,
        "mean_gap": None,
        "per_knob": {},
    }


@pytest.mark.parametrize(
    "knobs, inits, message",
    [
        (["wobble"], [0], "unknown knob 'wobble'"),
        (["drop"], [], "at least one knob and one init"),
    ],
)
def test_bad_pair_inputs_are_refused_before_building_an_env(knobs, inits, message):
    with pytest.raises(UserInputError, match=message):
        continuation_pairs("libero_object", 0, knobs, inits, seed=0)


@pytest.mark.sim
def test_real_pairs_branch_from_the_same_state():
    pairs = continuation_pairs("libero_object", 0, ["drop", "tilt"], [0], seed=0, window=25)
    assert pairs.skipped == {"drop": 0, "tilt": 0}
    assert [p.knob for p in pairs] == ["drop", "tilt"]
    assert pairs.metadata["suite"] == "libero_object" and pairs.metadata["task_index"] == 0
    for p in pairs:
        assert p.task == "libero_object/0" and p.init == 0 and p.branch_step > 0
        assert np.array_equal(p.clean.states[0], p.knobbed.states[0])
        assert not np.array_equal(p.clean.actions[0], p.knobbed.actions[0])
        for s in (p.clean, p.knobbed):
            assert 1 <= len(s.actions) <= 25 and s.states.shape == (len(s.actions), len(p.clean.states[0]))
            assert s.actions.shape == (len(s.actions), 7)
