"""Intervention headroom: can one changed decision make a policy's episode elegant, and does the critic find it?

JITI replaces one decision (an action, or a chunk of actions for a chunked policy) at a critical moment
and hands control back to the base policy. Whether that
can turn an inelegant episode into an elegant success depends first on the policy: if it tips the can at
every placement whatever happened before, no single choice repairs the episode and no critic can show a
gain. This diagnostic measures that ceiling in the simulator, by branching (JITI itself never looks
ahead). From each start, as in `elegant eval` with the same seed:

1. run the base policy, and every `every` steps from step `first` draw N candidates as JITI would
   (candidate 0 = the base plan) and score them with the critic (for a chunked policy `every` and
   `first` must be multiples of its chunk: it decides only there);
2. for every decision point and candidate, replay the episode to that step (the env is deterministic
   given its reset seed and the actions), execute the candidate plan, let the base policy finish, and
   judge the episode with the ITC monitor (a branch stops at its first violation: it can no longer be
   elegant).

Summarised over decision points: how often the choice matters at all, how often some eligible candidate
(within the trust radius) gives an elegant success where the base action does not (the headroom), how
often the critic's choice does (its hit rate), against a uniformly random eligible candidate and the
critic-free controls of JITI's modes `likelihood` and `consensus`; on base-elegant episodes, how often each
choice spoils the episode (each rate with its standard error over starts); and, where the eligible
candidates' outcomes differ, how well the critic's Q separates those that led to an elegant success from
those that did not (`outcome_auroc`, 0.5 = chance, with its standard error over the points,
`outcome_auroc_se`; apart for rescue and harm-avoidance points).
`rescore_headroom` recomputes all of it for another critic
from the stored states and candidates.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from base_suites import get_task, make_env
from base_suites.rollout import StepObserver, run_episode
from base_suites.runtime.errors import UserInputError
from elegant.evaluation.runner import episode_start, open_critic, open_policy
from elegant.intervention.config import JITIConfig
from elegant.intervention.jiti import check_critic_chunk, decide, draw_candidates, plan_distance
from elegant.intervention.modes.consensus import NearestMean
from elegant.intervention.modes.likelihood import MostProbable
from elegant.intervention.selectors import Choice, choose_candidate, eligible_candidates
from elegant.policies.adapters import as_policy
from elegant.policies.protocol import chunk_of
from elegant.reporting.report import save_figure


class _StopAtViolation(StepObserver):
    """Judges each step with the ITC monitor and, if asked, ends the episode at its first violation."""

    def __init__(self, monitor, stop: bool) -> None:
        self.monitor, self.stop = monitor, stop

    def after_step(self, env, action, obs, reward, info) -> bool:
        return not all(self.monitor.step(action).kept.values()) and self.stop


def _rollout(
    env,
    monitor,
    policy,
    chunk: int,
    init_index: int,
    reset_seed: int,
    prefix: Sequence[np.ndarray],
    stop_on_violation: bool,
    at_decision: Callable[[int, dict, np.ndarray], None] | None = None,
) -> tuple[list[np.ndarray], bool]:
    """Episode from the given start (`base_suites.rollout.run_episode`): `prefix` actions first, then the
    policy's. Returns the executed actions and whether the episode was an elegant success.
    `at_decision(t, obs, base_plan)` sees each of the policy's decisions (the policy decides or observes at
    every step, prefix included, so its history and its chunk boundaries match the base episode's)."""
    obs, _ = env.reset(seed=reset_seed, options={"init_state": init_index})
    monitor.reset()
    policy.reset(env.metadata, seed=reset_seed)
    actions: list[np.ndarray] = []
    queue: deque[np.ndarray] = deque()

    def act(obs: dict) -> np.ndarray:
        t = len(actions)
        if queue:
            policy.observe(obs)
        else:
            plan = decide(policy, obs, chunk)
            if at_decision is not None:
                at_decision(t, obs, plan)
            queue.extend(plan)
        action = queue.popleft()
        actions.append(prefix[t] if t < len(prefix) else action)
        return actions[-1]

    run = run_episode(env, act, obs, [_StopAtViolation(monitor, stop_on_violation)])
    if run.stopped:
        return actions, False
    return actions, bool(monitor.verdict(bool(run.info["success"])).elegant)


def branch_episode(
    env, monitor, policy, critic, init_index: int, reset_seed: int, *, every: int, first: int, n_candidates: int
) -> dict[str, Any]:
    """One start: the base episode's outcome and, per decision point, the state, the candidate plans, each
    candidate's Q, distance from the base plan (`plan_distance`) and elegant-success outcome (candidate 0's
    is the base episode's). The states and candidates let `rescore_headroom` judge another critic on the
    same outcomes without the simulator."""
    chunk = chunk_of(policy)
    drawn: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def draw(t: int, obs: dict, plan: np.ndarray) -> None:
        if t >= first and (t - first) % every == 0:
            candidates = draw_candidates(policy, obs, plan, n_candidates)
            # the policy's own density of each candidate, where it has one (mode "likelihood"'s choice)
            density = getattr(policy, "log_prob_plans", None)
            log_prob = None if density is None else np.asarray(density(obs, candidates)).round(4).tolist()
            drawn[t] = (np.array(obs["state"], dtype=np.float64), candidates, log_prob)

    actions, base_elegant = _rollout(env, monitor, policy, chunk, init_index, reset_seed, (), False, draw)
    points = []
    for t, (state, candidates, log_prob) in sorted(drawn.items()):
        if t + chunk >= len(actions):  # the episode ended within this decision: nothing left to choose
            continue
        outcomes = [base_elegant] + [
            _rollout(env, monitor, policy, chunk, init_index, reset_seed, [*actions[:t], *candidates[k]], True)[1]
            for k in range(1, len(candidates))
        ]
        points.append(
            {
                "step": t,
                "q": _scores(critic, state, candidates),
                "distance": plan_distance(candidates).round(4).tolist(),
                "elegant": outcomes,
                "state": state.tolist(),
                "candidates": np.asarray(candidates).tolist(),
                "log_prob": log_prob,
            }
        )
    return {
        "init_index": init_index,
        "reset_seed": reset_seed,
        "steps": len(actions),
        "base_elegant": base_elegant,
        "points": points,
    }


def _scores(critic, state: np.ndarray, candidates: np.ndarray) -> list[float]:
    """The critic's Q of each candidate plan (flattened, as the critic takes chunks) in `state`."""
    flat = np.asarray(candidates, dtype=np.float64).reshape(len(candidates), -1)
    return np.asarray(critic.q(np.asarray(state), flat), dtype=np.float64).round(4).tolist()


def rescore_headroom(result: Mapping[str, Any], critic: Any, jiti: JITIConfig) -> dict[str, Any]:
    """Judge another critic on branches already run: every decision point's Q recomputed from its stored
    state and candidates, the outcomes kept. Seconds instead of the hours of branching, so critics can be
    compared on the decisions that matter, with the simulator's own verdicts as ground truth; `jiti` says
    how the critic chooses (its trust radius and minimum gain)."""
    if "suite" not in result or any("candidates" not in p for e in result["episodes"] for p in e["points"]):
        raise UserInputError(
            "rescore: this headroom result stores no states and candidates (it was written before they were kept); "
            "branch again"
        )
    scorer = open_critic(critic)
    check_critic_chunk(scorer, result["chunk"])
    env = make_env(result["suite"], get_task(result["suite"], result["task"]).index, seed=0)
    try:
        scorer.bind(env.metadata)
    finally:
        env.close()
    episodes = [
        {
            **e,
            "points": [
                {**p, "q": _scores(scorer, np.asarray(p["state"]), np.asarray(p["candidates"]))} for p in e["points"]
            ],
        }
        for e in result["episodes"]
    ]
    return {**result, "episodes": episodes, "summary": summarize_headroom(episodes, jiti)}


def clustered_rate(groups: Sequence[Sequence[float]]) -> tuple[float | None, float | None]:
    """The pooled mean of values grouped by start, with its standard error treating the start, not the
    decision point, as the unit (the cluster-robust SE of a ratio of sums; None with fewer than 2 starts)."""
    groups = [list(g) for g in groups if len(g)]
    if not groups:
        return None, None
    sums, counts = np.array([sum(g) for g in groups]), np.array([len(g) for g in groups], dtype=float)
    rate = float(sums.sum() / counts.sum())
    if len(groups) < 2:
        return rate, None
    k = len(groups)
    return rate, float(np.sqrt(k / (k - 1) * np.sum((sums - rate * counts) ** 2)) / counts.sum())


def _controls(point: Mapping[str, Any], jiti: JITIConfig) -> dict[str, int]:
    """The candidate each critic-free control picks at a point (`elegant.intervention.modes`): consensus
    where the point stores its candidates, likelihood where it stores the policy's log-densities."""
    picks = {}
    distance = np.asarray(point["distance"])
    if "candidates" in point:
        choice = Choice(np.asarray(point["candidates"]), None, distance, np.random.default_rng(0), lambda: None)
        picks["consensus"] = NearestMean(jiti.trust_radius).select(choice)
    if point.get("log_prob") is not None:
        log_prob = np.asarray(point["log_prob"])
        choice = Choice(
            np.asarray(point.get("candidates", [])), None, distance, np.random.default_rng(0), lambda: log_prob
        )
        picks["likelihood"] = MostProbable(jiti.trust_radius).select(choice)
    return picks


def summarize_headroom(episodes: Sequence[dict[str, Any]], jiti: JITIConfig) -> dict[str, Any]:
    """Rates over decision points (see the module docstring), the critic choosing as `jiti` says (its trust
    radius and minimum gain); None where no point qualifies. Beside the critic and a random eligible
    candidate, the critic-free controls where the points allow them (`_controls`); each `*_hit` (on
    inelegant base episodes) and `*_harm` (on elegant ones) comes with its `*_se` over starts, and the
    outcome AUROC is given apart where the base episode was inelegant (`rescue_auroc`: can it find a
    rescue?) and elegant (`harm_avoidance_auroc`: does it rank the spoiling candidates low?)."""
    from critics.quality import auroc as ranking_auroc  # P(Q of an elegant outcome > Q of another), ties half

    def rate(values: list[float]) -> float | None:
        return float(np.mean(values)) if values else None

    matters, reachable, rescuable, auroc = [], [], [], []
    by_start: dict[str, list[list[float]]] = {}
    split_auroc: dict[str, list[float]] = {"rescue_auroc": [], "harm_avoidance_auroc": []}
    for episode in episodes:
        any_reachable = False
        kind = "harm" if episode["base_elegant"] else "hit"
        rows: dict[str, list[float]] = {}
        for point in episode["points"]:
            elegant = np.asarray(point["elegant"], dtype=bool)
            q, distance = np.asarray(point["q"]), np.asarray(point["distance"])
            eligible = eligible_candidates(distance, jiti.trust_radius)
            picks = {
                "critic": choose_candidate(q, distance, jiti.trust_radius, jiti.min_gain),
                **_controls(point, jiti),
            }
            matters.append(float(elegant.any() != elegant.all()))
            if elegant[eligible].any() and not elegant[eligible].all():
                value = ranking_auroc(q[eligible & elegant], q[eligible & ~elegant])
                auroc.append(value)
                split_auroc["harm_avoidance_auroc" if episode["base_elegant"] else "rescue_auroc"].append(value)
            random_elegant = float(elegant[eligible].mean())
            outcomes = {name: float(elegant[pick]) for name, pick in picks.items()} | {"random": random_elegant}
            for name, elegant_outcome in outcomes.items():
                rows.setdefault(f"{name}_{kind}", []).append(
                    1.0 - elegant_outcome if kind == "harm" else elegant_outcome
                )
            if not episode["base_elegant"]:
                rescued = bool(elegant[eligible].any())
                reachable.append(float(rescued))
                any_reachable |= rescued
        for name, values in rows.items():
            by_start.setdefault(name, []).append(values)
        if not episode["base_elegant"]:
            rescuable.append(float(any_reachable))
    summary: dict[str, Any] = {
        "episodes": len(episodes),
        "base_esr": rate([float(e["base_elegant"]) for e in episodes]),
        "decision_points": sum(len(e["points"]) for e in episodes),
        "choice_matters": rate(matters),
        "headroom": rate(reachable),
    }
    for name in ("critic", "random", "likelihood", "consensus"):
        for kind in ("hit", "harm"):
            value, se = clustered_rate(by_start.get(f"{name}_{kind}", []))
            if value is not None or name in ("critic", "random"):
                summary[f"{name}_{kind}"], summary[f"{name}_{kind}_se"] = value, se
    summary.update(
        {
            "rescuable_episodes": rate(rescuable),
            "outcome_auroc": rate(auroc),
            # spread of the per-point AUROCs over sqrt(points): with the 20-odd points a task's branches give,
            # critics 0.1 apart may not differ
            "outcome_auroc_se": float(np.std(auroc, ddof=1) / np.sqrt(len(auroc))) if len(auroc) > 1 else None,
            **{name: rate(values) for name, values in split_auroc.items()},
            "trust_radius": jiti.trust_radius,
        }
    )
    return summary


def intervention_headroom(
    suite: str,
    task: int,
    policy: Any,
    critic: Any,
    *,
    episodes: Sequence[int] = (0, 1, 2, 3),
    seed: int = 0,
    every: int = 15,
    first: int = 10,
    jiti: JITIConfig,
    max_steps: int | None = None,
    init_states: Sequence[int] | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Branch the starts of evaluation episodes `episodes` (indices, as `elegant eval --seed seed
    --init-states ...` numbers them) of one task; return {"summary": ..., "episodes": [...]}. `policy`
    and `critic` are directories or objects; `jiti` says how many candidates are drawn and how the critic
    chooses among them."""
    from tqdm import tqdm

    from itc import ITCMonitor

    if not episodes or min(episodes) < 0 or every < 1 or first < 0:
        raise UserInputError(
            f"headroom needs episode indices >= 0, every >= 1, first >= 0; got {list(episodes)}, {every}, {first}"
        )
    base = as_policy(open_policy(policy), seed=seed)
    chunk = chunk_of(base)
    if every % chunk or first % chunk:
        raise UserInputError(
            f"headroom: the policy decides every {chunk} steps, so every ({every}) and first ({first}) must be "
            f"multiples of {chunk}"
        )
    scorer = open_critic(critic)
    check_critic_chunk(scorer, chunk)
    spec = get_task(suite, task)
    env = make_env(suite, spec.index, seed=seed, max_steps=max_steps)
    try:
        monitor = ITCMonitor(env)
        scorer.bind(env.metadata)
        results = []
        for episode in tqdm(list(episodes), desc=f"headroom {suite}/{spec.index}", unit="ep", disable=not progress):
            init_index, reset_seed = episode_start(seed, suite, spec.index, episode, spec.n_init_states, init_states)
            results.append(
                branch_episode(
                    env,
                    monitor,
                    base,
                    scorer,
                    init_index,
                    reset_seed,
                    every=every,
                    first=first,
                    n_candidates=jiti.n_candidates,
                )
            )
    finally:
        env.close()
    return {
        "suite": suite,
        "task": spec.index,
        "chunk": chunk,
        "summary": summarize_headroom(results, jiti),
        "episodes": results,
    }


_ELEGANT, _ELEGANT_FAR = (0.20, 0.65, 0.30), (0.70, 0.88, 0.72)
_PLAIN, _PLAIN_FAR = (0.72, 0.72, 0.72), (0.93, 0.93, 0.93)


def plot_headroom(result: Mapping[str, Any], jiti: JITIConfig, path: Path) -> Path:
    """The intervention-headroom branches (`intervention_headroom`): one panel per start, one row per decision
    point, its candidates ordered by the critic's Q (best on the left); green where executing the
    candidate led to an elegant success, pale where it lies outside the trust radius; the base action
    outlined, the critic's choice dotted. Shows at a glance whether rescuing candidates exist and where
    the critic ranks them."""
    from matplotlib.figure import Figure

    episodes = [e for e in result["episodes"] if e["points"]]
    if not episodes:
        raise UserInputError("plot_headroom: no decision points to draw")
    n_cand = len(episodes[0]["points"][0]["q"])
    fig = Figure(figsize=(max(6.0, 3.0 * len(episodes)), 0.35 * max(len(e["points"]) for e in episodes) + 1.6))
    for i, episode in enumerate(episodes):
        ax = fig.add_subplot(1, len(episodes), i + 1)
        image = np.zeros((len(episode["points"]), n_cand, 3))
        for row, point in enumerate(episode["points"]):
            q, distance = np.asarray(point["q"]), np.asarray(point["distance"])
            order = np.argsort(-q, kind="stable")
            column = np.argsort(order)  # candidate k is drawn in column[k]
            near = eligible_candidates(distance, jiti.trust_radius)
            for col, k in enumerate(order):
                image[row, col] = (
                    (_ELEGANT if near[k] else _ELEGANT_FAR)
                    if point["elegant"][k]
                    else (_PLAIN if near[k] else _PLAIN_FAR)
                )
            ax.scatter([column[0]], [row], marker="s", s=60, facecolors="none", edgecolors="black", lw=1)
            chosen = choose_candidate(q, distance, jiti.trust_radius, jiti.min_gain)
            ax.scatter([column[chosen]], [row], marker="o", s=10, color="tab:red")
        ax.imshow(image, aspect="auto", interpolation="nearest")
        ax.set_yticks(range(len(episode["points"])), [str(p["step"]) for p in episode["points"]], fontsize=7)
        ax.set_xticks([0, n_cand - 1], ["best Q", "worst Q"], fontsize=7)
        ax.set_title(
            f"init {episode['init_index']}: base {'elegant' if episode['base_elegant'] else 'not elegant'}", fontsize=8
        )
        if i == 0:
            ax.set_ylabel("decision step")
    fig.suptitle(
        "candidates by critic rank: green = elegant success when executed (pale: outside trust radius); "
        "box = base action, dot = critic's choice",
        fontsize=8,
    )
    return save_figure(fig, path)
