"""Metrics of docs/design.md, section 8: episode metrics, LIBERO's lifelong metrics, LIBERO-PRO robustness.

Episode metrics read the records of `RUN/episodes.jsonl` (one dict per finished episode; keys used
here: task, success, elegant, violated, interventions, overrides, steps, decision_time, env_step_time).
The lifelong and robustness metrics take plain numbers so they serve success and elegant success alike:
call them once with success rates and once with elegant success rates ("elegant FWT/NBT/AUC", which no
existing benchmark reports).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from scipy.stats import binomtest

from annotations.format import CRITERIA
from base_suites.runtime.errors import UserInputError

Record = Mapping[str, Any]


def _require(records: Sequence[Record]) -> None:
    if not records:
        raise UserInputError("no finished episodes to compute metrics from")


def success_rate(records: Sequence[Record]) -> float:
    """Fraction of episodes whose task succeeded."""
    _require(records)
    return float(np.mean([bool(r["success"]) for r in records]))


def elegant_success_rate(records: Sequence[Record]) -> float:
    """ESR: fraction of episodes that succeeded with no violated window of any criterion."""
    _require(records)
    return float(np.mean([bool(r["elegant"]) for r in records]))


def violation_rates(records: Sequence[Record], criteria: Iterable[str] = CRITERIA) -> dict[str, float]:
    """Per criterion, the fraction of episodes with at least one violated window."""
    _require(records)
    return {c: float(np.mean([c in r["violated"] for r in records])) for c in criteria}


def success_with_violation(records: Sequence[Record], criteria: Iterable[str] = CRITERIA) -> dict[str, float]:
    """Per criterion, the fraction of episodes that succeeded with a violated window of it: where the gap
    between success and ESR comes from (an episode with two violated criteria counts under both)."""
    _require(records)
    return {c: float(np.mean([bool(r["success"]) and c in r["violated"] for r in records])) for c in criteria}


def rate_interval(hits: int, n: int, confidence: float = 0.95) -> list[float]:
    """Wilson score interval of a rate of `hits` in `n` episodes: at the 25-50 episodes a task gets here,
    a success rate or ESR is uncertain by +-10-20 points, and the interval says so."""
    if n < 1:
        raise UserInputError("no episodes to compute an interval from")
    interval = binomtest(int(hits), int(n)).proportion_ci(confidence_level=confidence, method="wilson")
    return [float(interval.low), float(interval.high)]


def paired_comparison(before: Sequence[Record], after: Sequence[Record], key: str) -> dict[str, Any]:
    """Two runs on the same starts (same seed, so the same init state and reset seed per episode), compared
    on the boolean record field `key` ("success" or "elegant") episode by episode.

    Pairs are the episodes with the same task and episode index whose init_index and seed agree. Returns
    pairs, the rates before and after over the pairs, difference (after - before), only_before /
    only_after (pairs where only that run has `key`) and p_value: McNemar's exact test, the two-sided
    binomial test of only_after against only_before (1.0 where they are all equal). Pairing removes the
    start-to-start variance that dominates the difference of two independent 25-episode rates."""

    def start(r: Record) -> tuple:
        return r["task"], int(r["episode"]), r.get("init_index"), r.get("seed")

    earlier = {start(r): r for r in before}
    pairs = [(earlier[start(r)], r) for r in after if start(r) in earlier]
    if not pairs:
        return {"pairs": 0}
    a = np.array([bool(p[key]) for p, _ in pairs])
    b = np.array([bool(q[key]) for _, q in pairs])
    only_before, only_after = int(np.sum(a & ~b)), int(np.sum(b & ~a))
    discordant = only_before + only_after
    return {
        "pairs": len(pairs),
        "before": float(a.mean()),
        "after": float(b.mean()),
        "difference": float(b.mean() - a.mean()),
        "only_before": only_before,
        "only_after": only_after,
        "p_value": float(binomtest(only_after, discordant).pvalue) if discordant else 1.0,
    }


def interventions_per_episode(records: Sequence[Record]) -> float:
    """Mean number of steps per episode at which JITI re-ranked candidates."""
    _require(records)
    return float(np.mean([r["interventions"] for r in records]))


def decision_overhead(records: Sequence[Record]) -> dict[str, float]:
    """Mean decision and env step time per step (weighted by episode length) and their ratio."""
    _require(records)
    steps = np.array([r["steps"] for r in records], dtype=np.float64)
    total = max(float(steps.sum()), 1.0)
    decision = float(np.dot(steps, [r["decision_time"] for r in records]) / total)
    env = float(np.dot(steps, [r["env_step_time"] for r in records]) / total)
    return {
        "decision_time": decision,
        "env_step_time": env,
        "decision_overhead": decision / env if env > 0 else float("nan"),
    }


def _block(records: Sequence[Record]) -> dict[str, Any]:
    return {
        "episodes": len(records),
        "success_rate": success_rate(records),
        "success_ci95": rate_interval(sum(bool(r["success"]) for r in records), len(records)),
        "esr": elegant_success_rate(records),
        "esr_ci95": rate_interval(sum(bool(r["elegant"]) for r in records), len(records)),
        "itc_violation_rate": violation_rates(records),
        "success_with_violation": success_with_violation(records),
        "interventions_per_episode": interventions_per_episode(records),
        "overrides_per_episode": float(np.mean([r["overrides"] for r in records])),
        "steps_per_episode": float(np.mean([r["steps"] for r in records])),
        **decision_overhead(records),
    }


def summarize(records: Sequence[Record]) -> dict[str, Any]:
    """All episode metrics, overall and per task (keyed by the records' task key, in first-seen order)."""
    _require(records)
    tasks: dict[str, list[Record]] = {}
    for r in records:
        tasks.setdefault(r["task"], []).append(r)
    return {**_block(records), "per_task": {key: _block(group) for key, group in tasks.items()}}


# ---- lifelong learning (LIBERO, Liu et al. 2023) --------------------------------------------------


def clamp_learning_curves(curves: np.ndarray, kept: Sequence[int] | None = None) -> np.ndarray:
    """LIBERO keeps the best checkpoint: from the kept point of each row on (default: the row's first
    maximum), every value is the value there. `kept` matters for curves of another measure than the one
    the checkpoint was chosen by (elegant success, with checkpoints kept by success)."""
    out = np.array(curves, dtype=np.float64)
    for k, row in enumerate(out):
        best = int(np.argmax(row)) if kept is None else int(kept[k])
        row[best:] = row[best]
    return out


def lifelong_metrics(S: np.ndarray, C: np.ndarray, kept: Sequence[int] | None = None) -> dict[str, Any]:
    """FWT, NBT and AUC as in LIBERO's `compute_metric`, for K tasks learned in order (0-indexed).

    S[i, j]: success on task j after learning task i (only i >= j is read). C[k, e]: success on task k
    at the e-th evaluation point while learning it (e = 0 before training), clamped here as LIBERO does
    (at `kept`, the evaluation point of each task's kept checkpoint, if given; else at C's own best).
    FWT = mean of the clamped C; NBT_k = mean over tau > k of S[k, k] - S[tau, k] (0 for the last task);
    AUC_k = (mean_e C[k, e] + sum over tau > k of S[tau, k]) / (K - k); NBT and AUC average over k.
    """
    S = np.asarray(S, dtype=np.float64)
    C = np.asarray(C, dtype=np.float64)
    if S.ndim != 2 or S.shape[0] != S.shape[1] or S.shape[0] == 0:
        raise UserInputError(f"lifelong success matrix S: expected a non-empty K x K array, got shape {S.shape}")
    K = S.shape[0]
    if C.ndim != 2 or C.shape[0] != K or C.shape[1] == 0:
        raise UserInputError(f"lifelong learning curves C: expected shape ({K}, E) with E >= 1, got {C.shape}")
    if kept is not None and len(kept) != K:
        raise UserInputError(f"lifelong kept checkpoints: expected {K} indices, got {len(kept)}")
    curves = clamp_learning_curves(C, kept)
    nbt = np.zeros(K)
    auc = np.zeros(K)
    for k in range(K):
        later = S[k + 1 :, k]
        if later.size:
            nbt[k] = float(np.mean(S[k, k] - later))
        auc[k] = (curves[k].mean() + later.sum()) / (K - k)
    return {
        "fwt": float(curves.mean()),
        "nbt": float(nbt.mean()),
        "auc": float(auc.mean()),
        "fwt_per_task": curves.mean(axis=1).tolist(),
        "nbt_per_task": nbt.tolist(),
        "auc_per_task": auc.tolist(),
    }


# ---- robustness (LIBERO-PRO, Zhou et al. 2025) ----------------------------------------------------


def robustness_metrics(rates: Mapping[str, float], original: str = "ori") -> dict[str, Any]:
    """Acc(ori), Acc(k) per perturbation axis, gap_k = Acc(ori) - Acc(k), PRO = mean over axes of Acc(k).

    `rates` maps "ori" (the unperturbed run) and each perturbation axis to a success rate (or an ESR,
    for the elegant version). `mean_gap` is the mean drop over the axes.
    """
    if original not in rates:
        raise UserInputError(f"robustness needs the unperturbed rate under key {original!r}; got keys {sorted(rates)}")
    axes = [k for k in rates if k != original]
    if not axes:
        raise UserInputError("robustness needs at least one perturbed axis besides the unperturbed rate")
    ori = float(rates[original])
    acc = {k: float(rates[k]) for k in axes}
    gap = {k: ori - acc[k] for k in axes}
    return {
        "acc_ori": ori,
        "acc": acc,
        "gap": gap,
        "pro": float(np.mean(list(acc.values()))),
        "mean_gap": float(np.mean(list(gap.values()))),
    }
