"""LIBERO-PRO's robustness table from constructed run summaries (no simulator): PRO averages the LIBERO-PRO
axes only, the language probes stand beside it, and every gap is Acc_ori - Acc (a drop is positive)."""

from __future__ import annotations

import pytest

from elegant.evaluation.robustness import _table

# Per suite and axis: (success rate, ESR); every axis has its own rate, so an axis counted in the wrong place
# or a gap of the wrong sign changes a number.
RATES = {
    "libero_object": {
        "ori": (0.75, 0.5),
        "object": (0.5, 0.25),
        "position": (0.25, 0.125),
        "probe_shuffled": (0.5, 0.375),
        "probe_empty": (1.0, 0.0),
    },
    "libero_goal": {
        "ori": (0.5, 0.25),
        "object": (0.375, 0.125),
        "position": (0.125, 0.0),
        "probe_shuffled": (0.25, 0.5),
        "probe_empty": (0.0, 0.125),
    },
}


def summary(success: float, esr: float) -> dict:
    """The fields of an `evaluate` summary the table reads."""
    return {"success_rate": success, "success_ci95": [0.0, 1.0], "esr": esr, "esr_ci95": [0.0, 0.5]}


def runs() -> dict:
    return {suite: {axis: summary(*rates) for axis, rates in axes.items()} for suite, axes in RATES.items()}


def expected_row(rates: dict[str, float]) -> dict:
    """The row by hand: Acc and gap per LIBERO-PRO axis, PRO the mean over those two, the probes apart."""
    ori = rates["ori"]
    pro_axes, probes = ("object", "position"), ("probe_shuffled", "probe_empty")
    return {
        "acc_ori": ori,
        "acc": {a: rates[a] for a in pro_axes},
        "gap": {a: ori - rates[a] for a in pro_axes},
        "pro": (rates["object"] + rates["position"]) / 2,
        "mean_gap": (2 * ori - rates["object"] - rates["position"]) / 2,
        "probes": {a: {"acc": rates[a], "gap": ori - rates[a]} for a in probes},
    }


@pytest.mark.parametrize("name, column", [("success", 0), ("elegant", 1)])
def test_pro_averages_the_libero_pro_axes_only_and_the_probes_stand_apart(name, column):
    """PRO is the mean Acc over the LIBERO-PRO axes run (object, position): the probes, with rates of their
    own, are neither in it nor in the per-axis accuracies and gaps, only under `probes`. The total row is
    the mean over suites of every rate."""
    table = _table(runs())[name]
    assert list(table) == ["libero_object", "libero_goal", "total"]
    for suite, axes in RATES.items():
        row = table[suite]
        assert row.pop("ci95") == {a: [0.0, 1.0] if column == 0 else [0.0, 0.5] for a in axes}
        rates = {a: r[column] for a, r in axes.items()}
        assert set(row["acc"]) == set(row["gap"]) == {"object", "position"}
        assert row == expected_row(rates)  # dyadic rates: every mean is exact
    total = {a: (RATES["libero_object"][a][column] + RATES["libero_goal"][a][column]) / 2 for a in RATES["libero_goal"]}
    assert "ci95" not in table["total"]
    assert set(table["total"]["acc"]) == {"object", "position"}
    assert table["total"] == expected_row(total)
    # the numbers themselves: libero_object's success PRO is (0.5 + 0.25) / 2, not the mean over four axes
    if name == "success":
        assert table["libero_object"]["pro"] == 0.375 and table["total"]["pro"] == 0.3125


def test_a_probe_gap_is_acc_ori_minus_the_probes_acc():
    """gap = Acc_ori - Acc_probe, as for the LIBERO-PRO axes: a probe that lowers success has a positive gap
    and one that raises it a negative gap."""
    table = _table(runs())
    assert table["success"]["libero_object"]["probes"] == {
        "probe_shuffled": {"acc": 0.5, "gap": 0.25},  # a drop from 0.75
        "probe_empty": {"acc": 1.0, "gap": -0.25},  # a rise from 0.75
    }
    assert table["elegant"]["libero_goal"]["probes"] == {
        "probe_shuffled": {"acc": 0.5, "gap": -0.25},  # a rise from 0.25
        "probe_empty": {"acc": 0.125, "gap": 0.125},  # a drop from 0.25
    }
    assert table["success"]["total"]["probes"]["probe_shuffled"] == {"acc": 0.375, "gap": 0.25}
