"""Metrics against hand-computed numbers: episode metrics, LIBERO's FWT/NBT/AUC, LIBERO-PRO robustness."""

import numpy as np
import pytest

from base_suites import UserInputError
from elegant.evaluation.metrics import (
    clamp_learning_curves,
    clustered_rate,
    decision_overhead,
    elegant_success_rate,
    interventions_per_episode,
    lifelong_metrics,
    paired_comparison,
    rate_interval,
    robustness_metrics,
    success_rate,
    success_with_violation,
    summarize,
    violation_rates,
)


def rec(task, success, elegant, violated, interventions, steps, dt, env):
    return {
        "task": task,
        "success": success,
        "elegant": elegant,
        "violated": violated,
        "interventions": interventions,
        "overrides": interventions // 2,
        "steps": steps,
        "decision_time": dt,
        "env_step_time": env,
    }


RECORDS = [
    rec("s/0", True, True, [], 2, 10, 0.001, 0.01),
    rec("s/0", True, False, ["collision"], 4, 20, 0.002, 0.01),
    rec("s/1", False, False, ["alignment", "collision"], 0, 30, 0.0, 0.02),
]


def test_episode_metrics():
    assert success_rate(RECORDS) == pytest.approx(2 / 3)
    assert elegant_success_rate(RECORDS) == pytest.approx(1 / 3)
    assert violation_rates(RECORDS) == pytest.approx(
        {"sequence": 0.0, "pose_accuracy": 0.0, "alignment": 1 / 3, "collision": 2 / 3}
    )
    assert interventions_per_episode(RECORDS) == pytest.approx(2.0)
    timing = decision_overhead(RECORDS)  # weighted by steps: (10*1 + 20*2 + 0) ms / 60 steps
    assert timing["decision_time"] == pytest.approx(0.05 / 60)
    assert timing["env_step_time"] == pytest.approx(0.9 / 60)
    assert timing["decision_overhead"] == pytest.approx(0.05 / 0.9)


def test_summary_overall_and_per_task():
    s = summarize(RECORDS)
    assert s["episodes"] == 3 and s["overrides_per_episode"] == pytest.approx(1.0) and s["steps_per_episode"] == 20
    assert list(s["per_task"]) == ["s/0", "s/1"]
    a, b = s["per_task"]["s/0"], s["per_task"]["s/1"]
    assert (a["success_rate"], a["esr"], a["itc_violation_rate"]["collision"], a["interventions_per_episode"]) == (
        1.0,
        0.5,
        0.5,
        3.0,
    )
    assert (b["success_rate"], b["esr"], b["itc_violation_rate"]["alignment"]) == (0.0, 0.0, 1.0)


def test_success_with_violation_counts_only_successful_episodes():
    # the failed episode's collision does not count: it explains a lost success, not a lost elegant success
    assert success_with_violation(RECORDS) == pytest.approx(
        {"sequence": 0.0, "pose_accuracy": 0.0, "alignment": 0.0, "collision": 1 / 3}
    )
    assert summarize(RECORDS)["success_with_violation"]["collision"] == pytest.approx(1 / 3)


def test_rate_interval_is_wilsons():
    z, n, p = 1.959963984540054, 25, 16 / 25
    centre, half = (
        (p + z * z / (2 * n)) / (1 + z * z / n),
        z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n),
    )
    assert rate_interval(16, 25) == pytest.approx([centre - half, centre + half])
    low, high = rate_interval(0, 10)
    assert low == 0.0 and 0.2 < high < 0.35  # never a zero-width interval at 0 of 10
    assert all(rate_interval(0, n)[0] == 0.0 and rate_interval(n, n)[1] == 1.0 for n in range(1, 60))
    assert summarize(RECORDS)["esr_ci95"] == pytest.approx(rate_interval(1, 3))
    with pytest.raises(UserInputError, match="no episodes"):
        rate_interval(0, 0)


def start(episode, success, elegant, seed=7, task="s/0"):
    return {
        "task": task,
        "episode": episode,
        "init_index": episode + 25,
        "seed": seed,
        "success": success,
        "elegant": elegant,
    }


def test_paired_comparison_pairs_identical_starts_and_applies_mcnemar():
    before = [start(e, e < 4, False) for e in range(10)]
    after = [start(e, e < 4, e < 6) for e in range(10)]
    after += [start(10, True, True)]  # no partner in `before`
    after[9] = start(9, True, True, seed=8)  # same episode index, another reset seed: not the same start
    elegant = paired_comparison(before, after, "elegant")
    assert elegant["pairs"] == 9 and (elegant["only_after"], elegant["only_before"]) == (6, 0)
    assert elegant["difference"] == pytest.approx(6 / 9) and elegant["p_value"] == pytest.approx(2 * 0.5**6)
    success = paired_comparison(before, after, "success")
    assert success["difference"] == 0.0 and success["p_value"] == 1.0  # no discordant pair
    assert paired_comparison(before, [start(0, True, True, task="s/1")], "success") == {"pairs": 0}


def test_no_records_is_a_user_error():
    with pytest.raises(UserInputError, match="no finished episodes"):
        summarize([])


def test_clamping_keeps_the_best_checkpoint():
    curves = clamp_learning_curves([[0.0, 0.6, 0.8, 0.7], [0.1, 0.9, 0.5, 0.9], [0.3, 0.2, 0.1, 0.0]])
    assert curves.tolist() == [[0.0, 0.6, 0.8, 0.8], [0.1, 0.9, 0.9, 0.9], [0.3, 0.3, 0.3, 0.3]]


S = np.array([[0.8, np.nan, np.nan], [0.6, 0.9, np.nan], [0.4, 0.7, 1.0]])  # only i >= j is read
C = np.array([[0.0, 0.6, 0.8, 0.7], [0.1, 0.9, 0.5, 0.9], [0.2, 0.4, 1.0, 0.6]])


def test_clamping_at_given_kept_points():
    # Elegant curves are clamped where the checkpoint was kept by success, not at their own maximum.
    curves = clamp_learning_curves([[0.0, 0.6, 0.2, 0.7], [0.5, 0.1, 0.9, 0.0]], kept=[2, 0])
    assert curves.tolist() == [[0.0, 0.6, 0.2, 0.2], [0.5, 0.5, 0.5, 0.5]]
    with pytest.raises(UserInputError, match="expected 2 indices"):
        lifelong_metrics(np.eye(2), np.zeros((2, 3)), kept=[0])


def test_lifelong_metrics_by_hand():
    m = lifelong_metrics(S, C)
    # clamped curve means: 0.55, 0.70, 0.65
    assert m["fwt"] == pytest.approx((0.55 + 0.70 + 0.65) / 3)
    # NBT_0 = mean(0.8-0.6, 0.8-0.4) = 0.3; NBT_1 = 0.9-0.7 = 0.2; NBT_2 = 0
    assert m["nbt_per_task"] == pytest.approx([0.3, 0.2, 0.0]) and m["nbt"] == pytest.approx(0.5 / 3)
    # AUC_0 = (0.55 + 0.6 + 0.4) / 3; AUC_1 = (0.70 + 0.7) / 2; AUC_2 = 0.65
    assert m["auc_per_task"] == pytest.approx([1.55 / 3, 0.7, 0.65])
    assert m["auc"] == pytest.approx((1.55 / 3 + 0.7 + 0.65) / 3)


def test_lifelong_metrics_match_libero_loop_semantics_on_random_matrices():
    """LIBERO's compute_metric: bwt_k sums S[k,k]-S[tau,k] over tau>k and divides by K-k-1 only when
    k+1 < K; auc_k adds the mean clamped curve and divides by K-k; fwt averages the clamped curves."""
    rng = np.random.default_rng(0)
    K, E = 5, 11
    S_, C_ = rng.uniform(size=(K, K)), rng.uniform(size=(K, E))
    curves = clamp_learning_curves(C_)
    bwt = auc = 0.0
    for k in range(K):
        bwt_k = sum(S_[k, k] - S_[t, k] for t in range(k + 1, K))
        auc_k = sum(S_[t, k] for t in range(k + 1, K))
        if k + 1 < K:
            bwt_k /= K - k - 1
        bwt += bwt_k
        auc += (auc_k + curves[k].mean()) / (K - k)
    m = lifelong_metrics(S_, C_)
    assert (m["fwt"], m["nbt"], m["auc"]) == pytest.approx((curves.mean(), bwt / K, auc / K))


def test_lifelong_metrics_single_task_and_bad_shapes():
    m = lifelong_metrics([[0.7]], [[0.2, 0.7, 0.5]])
    assert (m["fwt"], m["nbt"], m["auc"]) == pytest.approx((1.6 / 3, 0.0, 1.6 / 3))  # clamped: 0.2, 0.7, 0.7
    with pytest.raises(UserInputError, match="K x K"):
        lifelong_metrics(np.zeros((2, 3)), np.zeros((2, 4)))
    with pytest.raises(UserInputError, match=r"expected shape \(2, E\)"):
        lifelong_metrics(np.zeros((2, 2)), np.zeros((3, 4)))


def test_robustness_metrics_by_hand():
    r = robustness_metrics({"ori": 0.9, "object": 0.6, "init": 0.1, "language": 0.8, "env": 0.5})
    assert r["acc_ori"] == 0.9
    assert r["gap"] == pytest.approx({"object": 0.3, "init": 0.8, "language": 0.1, "env": 0.4})
    assert r["pro"] == pytest.approx(0.5) and r["mean_gap"] == pytest.approx(0.4)
    with pytest.raises(UserInputError, match="unperturbed"):
        robustness_metrics({"init": 0.1})
    with pytest.raises(UserInputError, match="at least one perturbed axis"):
        robustness_metrics({"ori": 0.9})


def test_lifelong_metrics_clamp_at_the_kept_checkpoints_not_at_their_own_best():
    """Elegant curves are clamped where the checkpoint was kept by success: FWT and AUC then differ from
    clamping at the elegant curve's own maximum, by hand."""
    S_ = np.array([[0.4, 0.0], [0.2, 0.6]])
    C_ = np.array([[0.0, 0.6, 0.2, 0.7], [0.5, 0.1, 0.9, 0.0]])
    kept = [2, 0]  # clamped rows: [0, 0.6, 0.2, 0.2] and [0.5, 0.5, 0.5, 0.5]
    m = lifelong_metrics(S_, C_, kept=kept)
    assert m["fwt_per_task"] == pytest.approx([0.25, 0.5]) and m["fwt"] == pytest.approx(0.375)
    assert m["auc_per_task"] == pytest.approx([(0.25 + 0.2) / 2, 0.5]) and m["auc"] == pytest.approx(0.3625)
    own = lifelong_metrics(S_, C_)  # at their own maxima: [0, 0.6, 0.2, 0.7] and [0.5, 0.1, 0.9, 0.9]
    assert own["fwt"] == pytest.approx((1.5 / 4 + 2.4 / 4) / 2) and own["fwt"] != pytest.approx(m["fwt"])


def test_intervals_count_starts_not_episodes():
    distinct = [start(e, e < 16, False) for e in range(25)]
    assert clustered_rate(distinct, "success")["interval"] == pytest.approx(rate_interval(16, 25))  # Wilson
    repeated = distinct + [dict(r, episode=r["episode"] + 25) for r in distinct]  # each start twice, the same
    twice = clustered_rate(repeated, "success")
    assert twice["rate"] == pytest.approx(16 / 25) and (twice["starts"], twice["episodes_per_start"]) == (25, 2.0)
    assert twice["interval"] == pytest.approx(rate_interval(16, 25))  # identical repeats do not narrow it
    full = [
        dict(r, violated=[], interventions=0, overrides=0, steps=1, decision_time=0, env_step_time=1) for r in repeated
    ]
    assert summarize(full)["success_ci95"] == pytest.approx(rate_interval(16, 25)) and summarize(full)["starts"] == 25
    split = [start(e % 20, e < 20, False) for e in range(40)]  # every start once each way: no start effect
    assert clustered_rate(split, "success")["icc"] == 0.0
    assert clustered_rate(split, "success")["interval"] == pytest.approx(rate_interval(20, 40))
    always = [start(e % 5, True, True) for e in range(20)]  # nothing varies anywhere: count the 5 starts
    assert clustered_rate(always, "elegant")["interval"] == pytest.approx(rate_interval(5, 5))


def test_the_paired_test_takes_the_start_as_its_unit():
    before = [start(e % 10, False, False) for e in range(20)]  # 10 starts, each run twice
    after = [dict(r, elegant=r["init_index"] - 25 < 6) for r in before]
    elegant = paired_comparison(before, after, "elegant")
    assert (elegant["only_after"], elegant["starts"], elegant["starts_better"], elegant["starts_worse"]) == (
        12,
        10,
        6,
        0,
    )
    assert elegant["p_value"] == pytest.approx(2 * 0.5**6)  # six starts, not twelve episodes
