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
from scipy.stats import binomtest, norm

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


def start_keys(records: Sequence[Record]) -> list[tuple]:
    """The start each episode ran from: its task and init state. Episodes of one start are not independent
    (a deterministic policy repeats itself from the same start), so the start is the statistical unit.
    A record without an init state counts as a start of its own."""
    return [
        (r["task"], int(r["init_index"])) if r.get("init_index") is not None else ("record", i)
        for i, r in enumerate(records)
    ]


def wilson_interval(rate: float, n: float, confidence: float = 0.95) -> list[float]:
    """Wilson score interval of a rate observed over `n` (possibly effective, non-integer) trials."""
    if not n > 0:
        raise UserInputError("no episodes to compute an interval from")
    z = float(norm.ppf(0.5 + confidence / 2))
    scale = 1.0 + z * z / n
    center = (rate + z * z / (2 * n)) / scale
    half = z * np.sqrt(rate * (1.0 - rate) / n + z * z / (4 * n * n)) / scale
    # the interval holds the rate exactly (rounding would otherwise leave 1 - 1e-16 at a rate of 1)
    return [float(min(max(0.0, center - half), rate)), float(max(min(1.0, center + half), rate))]


def rate_interval(hits: int, n: int, confidence: float = 0.95) -> list[float]:
    """Wilson score interval of `hits` in `n` independent episodes (each from its own start)."""
    if n < 1:
        raise UserInputError("no episodes to compute an interval from")
    return wilson_interval(hits / n, n, confidence)


def clustered_rate(records: Sequence[Record], key: str, confidence: float = 0.95) -> dict[str, Any]:
    """The rate of the boolean field `key` with an interval that counts starts, not episodes.

    The point estimate is the plain rate over episodes. The interval is Wilson's over the effective number
    of episodes N / (1 + (m - 1) * icc) (Kish's design effect; m the mean episodes per start, icc the
    intra-start correlation by the ANOVA estimator, clipped to [0, 1], taken as 1 where no start varies):
    one episode per start gives Wilson over the starts, and identical repeats of a start count once.
    Returns rate, interval (at `confidence`), starts, episodes_per_start, icc and effective_episodes."""
    _require(records)
    groups: dict[tuple, list[bool]] = {}
    for start, r in zip(start_keys(records), records):
        groups.setdefault(start, []).append(bool(r[key]))
    sizes = np.array([len(g) for g in groups.values()], dtype=np.float64)
    means = np.array([np.mean(g) for g in groups.values()])
    n, k = float(sizes.sum()), len(groups)
    rate = float(np.dot(sizes, means) / n)
    icc = _intra_start_correlation(sizes, means, rate) if n > k else 0.0
    effective = n / (1.0 + (n / k - 1.0) * icc)
    return {
        "rate": rate,
        "interval": wilson_interval(rate, effective, confidence),
        "starts": k,
        "episodes_per_start": n / k,
        "icc": icc,
        "effective_episodes": effective,
    }


def _intra_start_correlation(sizes: np.ndarray, means: np.ndarray, rate: float) -> float:
    """ANOVA estimator of the intra-cluster correlation of a binary outcome, clipped to [0, 1]."""
    n, k = float(sizes.sum()), len(sizes)
    within = float(np.dot(sizes, means * (1.0 - means)) / (n - k))
    if within == 0.0:
        return 1.0  # no start varies: its repeats carry no new information
    between = float(np.dot(sizes, (means - rate) ** 2) / (k - 1)) if k > 1 else 0.0
    n0 = (n - float(np.dot(sizes, sizes)) / n) / (k - 1) if k > 1 else n
    return float(np.clip((between - within) / (between + (n0 - 1.0) * within), 0.0, 1.0))


def episode_pairs(before: Sequence[Record], after: Sequence[Record]) -> list[tuple[Record, Record]]:
    """The episodes two runs share, in `after`'s order: same task and episode index, and the same init state
    and reset seed (runs with the same seed start each episode alike)."""

    def episode(r: Record) -> tuple:
        return r["task"], int(r["episode"]), r.get("init_index"), r.get("seed")

    earlier = {episode(r): r for r in before}
    return [(earlier[episode(r)], r) for r in after if episode(r) in earlier]


def paired_comparison(before: Sequence[Record], after: Sequence[Record], key: str) -> dict[str, Any]:
    """Two runs on the same starts (same seed, so the same init state and reset seed per episode), compared
    on the boolean record field `key` ("success" or "elegant").

    Pairs are the episodes with the same task and episode index whose init_index and seed agree. Returns
    pairs, the rates before and after over the pairs, difference (after - before), only_before /
    only_after (pairs where only that run has `key`), and the test with the start as the unit: starts,
    starts_better / starts_worse (starts whose mean over their pairs rose / fell) and p_value, the exact
    two-sided sign test of starts_better against starts_worse (1.0 where none differs). With one episode
    per start it is McNemar's exact test; repeated episodes of a start do not count as more evidence."""

    pairs = episode_pairs(before, after)
    if not pairs:
        return {"pairs": 0}
    a = np.array([bool(p[key]) for p, _ in pairs])
    b = np.array([bool(q[key]) for _, q in pairs])
    by_start: dict[tuple, list[int]] = {}
    for start, x, y in zip(start_keys([later for _, later in pairs]), a, b):
        by_start.setdefault(start, []).append(int(y) - int(x))
    changes = np.array([np.mean(d) for d in by_start.values()])
    better, worse = int(np.sum(changes > 0)), int(np.sum(changes < 0))
    return {
        "pairs": len(pairs),
        "before": float(a.mean()),
        "after": float(b.mean()),
        "difference": float(b.mean() - a.mean()),
        "only_before": int(np.sum(a & ~b)),
        "only_after": int(np.sum(b & ~a)),
        "starts": len(by_start),
        "starts_better": better,
        "starts_worse": worse,
        "p_value": float(binomtest(better, better + worse).pvalue) if better + worse else 1.0,
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
    success, elegant = clustered_rate(records, "success"), clustered_rate(records, "elegant")
    return {
        "episodes": len(records),
        "starts": success["starts"],
        "episodes_per_start": success["episodes_per_start"],
        "success_rate": success["rate"],
        "success_ci95": success["interval"],
        "esr": elegant["rate"],
        "esr_ci95": elegant["interval"],
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
