"""Quality knobs: validation and the rates at which mixed collections apply them (no simulator)."""

import numpy as np
import pytest

from base_suites import UserInputError
from base_suites.experts import KNOBS, QUALITY_PRESETS, draw_knobs, knob_rates, parse_quality


def test_presets_and_mappings_resolve():
    assert knob_rates("clean") == {k: 0.0 for k in KNOBS}
    assert knob_rates("mixed") == QUALITY_PRESETS["mixed"]
    assert knob_rates({"drop": 0.5})["drop"] == 0.5 and knob_rates({"drop": 0.5})["tilt"] == 0.0
    assert parse_quality("drop=0.3,tilt=1") == {"drop": 0.3, "tilt": 1.0}


@pytest.mark.parametrize(
    "bad, message",
    [
        ("sloppy", "unknown quality"),
        ({"wobble": 0.2}, "unknown quality knob"),
        ({"drop": 1.5}, "outside"),
    ],
)
def test_bad_quality_is_refused(bad, message):
    with pytest.raises(UserInputError, match=message):
        knob_rates(bad)
    with pytest.raises(UserInputError, match="knob=probability"):
        parse_quality("drop=lots")


def test_mixed_knob_rates_match_requested_within_sampling_error():
    rates = knob_rates("mixed")
    n = 2000
    drawn = [draw_knobs(rates, seed=3, episode=i)[0] for i in range(n)]
    for knob, p in rates.items():
        observed = np.mean([d[knob] for d in drawn])
        assert abs(observed - p) < 4 * np.sqrt(p * (1 - p) / n) + 1e-9, knob


def test_knob_draws_are_seeded_per_episode():
    rates = knob_rates("mixed")
    assert draw_knobs(rates, 1, 7)[0] == draw_knobs(rates, 1, 7)[0]
    assert any(draw_knobs(rates, 1, i)[0] != draw_knobs(rates, 2, i)[0] for i in range(20))


def test_the_short_way_round_is_taken_only_when_asked():
    """A parallel gripper grasps the same at yaw and yaw + pi. By default the plain grasp is kept (one
    hand orientation per grasp for cloned policies); `shortest` takes whichever the hand turns to the
    short way (a drawer push after a 150 deg turn sent OSC through the wrist's pitch stop)."""
    from base_suites.experts.control import grasp_rotation, nearest_grasp_rotation, rotation_error

    current = grasp_rotation(0.0)
    yaw = np.deg2rad(120)
    plain = nearest_grasp_rotation(yaw, current, wrist=0.0)
    short = nearest_grasp_rotation(yaw, current, wrist=0.0, shortest=True)
    assert np.allclose(plain, grasp_rotation(yaw))
    assert np.allclose(short, grasp_rotation(yaw + np.pi))
    assert abs(rotation_error(short, current)[2]) < abs(rotation_error(plain, current)[2])
    assert np.allclose(
        nearest_grasp_rotation(np.deg2rad(30), current, wrist=0.0, shortest=True), grasp_rotation(np.deg2rad(30))
    )
