"""JITI's decision rule on hand-made Q sequences, its modes, thresholds, warm-up and candidate sources.

The critic stand-in scores Q(s, a) = base_q[t] + a[0], where the state carries the step t: the base
action (a[0] = 0) scores exactly the hand-made value and candidates can be ranked by their first entry.
"""

import numpy as np
import pytest

from base_suites import UserInputError
from elegant.intervention.config import JITIConfig
from elegant.intervention.jiti import JITI, plan_distance

META = {"suite": "libero_object", "task_index": 0, "state_layout": [["t", 1]]}
# The settings these unit tests were written against (JITI's defaults are the recipe's): the deviation
# trigger on an absolute threshold, a base warm-up of 10 decisions and no trust radius; each test sets what it
# examines on top.
UNIT = JITIConfig(
    window=10, threshold=1.0, threshold_mode="absolute", trigger="deviation", warmup="base", trust_radius=None
)


def make_jiti(policy, critic, config=UNIT, **settings):
    return JITI(policy, critic, config, **settings)


BASE = np.array([0.0, 0.1, -0.2, 0.0, 0.0, 0.0, -1.0])


class ScriptedCritic:
    """Q(s, a) = base_q[t] + a[0]; remembers every batch it scored and every bind."""

    def __init__(self, base_q):
        self.base_q = list(base_q)
        self.batches, self.bound = [], []

    def bind(self, metadata):
        self.bound.append(metadata)

    def q(self, state, actions):
        self.batches.append(np.array(actions))
        return self.base_q[int(state[0])] + np.asarray(actions)[:, 0]


class SamplingPolicy:
    """Deterministic base action; `sample` returns candidates whose first entry grows with the row."""

    def __init__(self):
        self.samples, self.resets = 0, []

    def __call__(self, obs):
        return BASE.copy()

    def sample(self, obs, n):
        self.samples += 1
        out = np.repeat(BASE[None], n, axis=0)
        out[:, 0] = np.arange(n) / 100.0
        return out

    def reset(self, metadata=None, *, seed=None):
        self.resets.append((metadata, seed))


def rollout(jiti, steps):
    jiti.reset(META, seed=0)
    return [jiti({"state": np.array([float(t)])}) for t in range(steps)]


def test_no_intervention_when_q_is_flat():
    jiti = make_jiti(SamplingPolicy(), ScriptedCritic([5.0] * 30), window=10, threshold=0.5)
    actions = rollout(jiti, 30)
    assert jiti.interventions == 0
    assert all(np.array_equal(a, BASE) for a in actions)
    assert [d.mean for d in jiti.log[10:]] == [5.0] * 20 and all(d.dq == 0.0 for d in jiti.log[10:])


def test_intervention_on_a_jump_executes_the_argmax_and_feeds_its_q_to_the_window():
    q = [5.0] * 30
    q[15] = 8.0
    policy, critic = SamplingPolicy(), ScriptedCritic(q)
    jiti = make_jiti(policy, critic, window=10, threshold=0.5, n_candidates=16)
    actions = rollout(jiti, 30)
    assert [d.step for d in jiti.log if d.intervened] == [15]
    d = jiti.log[15]
    assert d.q == 8.0 and d.mean == 5.0 and d.dq == 3.0
    assert d.chosen == 15 and d.chosen_q == pytest.approx(8.15)  # argmax: the largest first entry
    assert actions[15][0] == pytest.approx(0.15) and policy.samples == 1
    # the executed action's q entered the window: the next mean includes 8.15, not 8.0
    assert jiti.log[16].mean == pytest.approx((9 * 5.0 + 8.15) / 10)
    # step 15 scored the base action alone, then its N - 1 alternatives (candidate 0 reuses the base score)
    assert len(critic.batches[15]) == 1 and np.array_equal(critic.batches[15][0], BASE)
    assert len(critic.batches[16]) == 15 and not np.any(np.all(critic.batches[16] == BASE, axis=1))


def test_warm_up_never_intervenes_before_the_window_is_full():
    q = [5.0] * 14
    q[3] = 50.0
    jiti = make_jiti(SamplingPolicy(), ScriptedCritic(q), window=10, threshold=0.5)
    rollout(jiti, 14)
    assert all(d.mean is None and d.dq is None and not d.intervened for d in jiti.log[:10])
    assert jiti.log[10].mean == pytest.approx((9 * 5 + 50) / 10)
    assert jiti.log[10].intervened  # step 10: the spike at step 3 is in the full window


def test_threshold_in_units_of_the_window_std():
    q = [4.0, 6.0] * 5 + [7.0, 7.5]  # window mean 5, std 1
    jiti = make_jiti(SamplingPolicy(), ScriptedCritic(q), window=10, threshold=2.0, threshold_mode="std")
    rollout(jiti, 11)
    d = jiti.log[10]
    assert d.std == pytest.approx(1.0) and d.tau == pytest.approx(2.0) and d.dq == pytest.approx(2.0)
    assert not d.intervened  # dq <= tau keeps the base action
    q2 = [4.0, 6.0] * 5 + [7.5]
    jiti2 = make_jiti(SamplingPolicy(), ScriptedCritic(q2), window=10, threshold=2.0, threshold_mode="std")
    rollout(jiti2, 11)
    assert jiti2.log[10].intervened
    # the same deviation is not critical for an absolute threshold of 3
    jiti3 = make_jiti(SamplingPolicy(), ScriptedCritic(q2), window=10, threshold=3.0)
    rollout(jiti3, 11)
    assert not jiti3.log[10].intervened and jiti3.log[10].tau == 3.0


def test_the_drop_trigger_ignores_a_climbing_q_and_fires_on_a_fall():
    """A value that climbs as the task progresses leaves every score above the lagging mean: the symmetric
    deviation fires all along the climb, the one-sided drop trigger only where q falls below the mean."""
    climb = [float(t) for t in range(12)] + [3.0]
    deviation = make_jiti(SamplingPolicy(), ScriptedCritic(climb), window=4, threshold=1.0)
    rollout(deviation, 13)
    assert [d.step for d in deviation.log if d.intervened] == [4, 5, 6, 7, 8, 9, 10, 11, 12]
    drop = make_jiti(SamplingPolicy(), ScriptedCritic(climb), window=4, threshold=1.0, trigger="drop")
    rollout(drop, 13)
    assert [d.step for d in drop.log if d.intervened] == [12]  # 3 after a window of 8-11: the fall
    assert drop.log[12].dq == pytest.approx(abs(3.0 - drop.log[12].mean)) and drop.config()["trigger"] == "drop"


def test_mode_always_reselects_every_step_and_base_wins_ties():
    policy, critic = SamplingPolicy(), ScriptedCritic([1.0] * 12)
    jiti = make_jiti(policy, critic, window=10, mode="always", n_candidates=4)
    actions = rollout(jiti, 12)
    assert jiti.interventions == 12 and policy.samples == 12
    assert all(len(b) == 4 and np.array_equal(b[0], BASE) for b in critic.batches)
    assert all(d.chosen == 3 for d in jiti.log) and actions[0][0] == pytest.approx(0.03)

    class FlatCritic(ScriptedCritic):
        def q(self, state, actions):
            return np.zeros(len(actions))

    tied = make_jiti(SamplingPolicy(), FlatCritic([]), mode="always", n_candidates=4)
    acts = rollout(tied, 3)
    assert all(d.chosen == 0 for d in tied.log) and all(np.array_equal(a, BASE) for a in acts)


def test_mode_base_never_intervenes_but_logs_q_without_window_statistics():
    q = [5.0] * 20
    q[12] = 100.0
    policy = SamplingPolicy()
    jiti = make_jiti(policy, ScriptedCritic(q), mode="base")
    actions = rollout(jiti, 20)
    assert jiti.interventions == 0 and policy.samples == 0
    # a base run records no window settings, so it logs no statistics of a window
    assert [d.q for d in jiti.log] == q and all(d.mean is None and d.dq is None and d.tau is None for d in jiti.log)
    assert all(np.array_equal(a, BASE) for a in actions)
    without = make_jiti(policy, None, mode="base")
    rollout(without, 3)
    assert [d.q for d in without.log] == [None] * 3
    with pytest.raises(UserInputError, match="needs a critic"):
        make_jiti(policy, None, mode="jiti")


def test_perturbation_fallback_for_plain_callables_is_clipped_and_seeded():
    at_bounds = np.array([1.0, -1.0, 1.0, 0.0, 0.0, 0.0, 1.0])

    def plain(obs):
        return at_bounds

    def run(seed):
        critic = ScriptedCritic([0.0] * 5)
        jiti = make_jiti(plain, critic, mode="always", n_candidates=8, noise_scale=0.5)
        jiti.reset(META, seed=seed)
        for t in range(5):
            jiti({"state": np.array([float(t)])})
        return np.stack(critic.batches)

    batches = run(seed=3)
    assert batches.shape == (5, 8, 7)
    assert np.all(np.abs(batches) <= 1.0) and np.all(batches[:, 0] == at_bounds)
    assert np.all(batches[:, 1:, 3:6] != 0.0)  # unclipped dimensions were perturbed
    assert np.array_equal(run(seed=3), batches) and not np.array_equal(run(seed=4), batches)


def test_reset_forwards_to_policy_binds_critic_and_clears_window():
    policy, critic = SamplingPolicy(), ScriptedCritic([5.0] * 12)
    jiti = make_jiti(policy, critic, window=10)
    rollout(jiti, 12)
    jiti.reset(META, seed=7)
    assert policy.resets[-1] == (META, 7) and critic.bound[-1] is META
    assert jiti.log == [] and jiti.interventions == 0
    jiti({"state": np.array([0.0])})
    assert jiti.log[0].mean is None  # the window restarted empty


def test_trace_has_one_column_per_field_and_one_row_per_step():
    jiti = make_jiti(SamplingPolicy(), ScriptedCritic([5.0] * 4), window=2)
    rollout(jiti, 4)
    trace = jiti.trace()
    assert set(trace) >= {
        "step",
        "q",
        "mean",
        "dq",
        "intervened",
        "chosen",
        "chosen_q",
        "time",
        "candidate_q",
        "action_change",
    }
    for intervened, cand, chosen_q, change in zip(
        trace["intervened"], trace["candidate_q"], trace["chosen_q"], trace["action_change"]
    ):
        assert (cand is not None) == intervened
        if intervened:
            assert abs(max(cand) - chosen_q) < 1e-3 and change >= 0.0
    assert all(len(v) == 4 for v in trace.values()) and trace["step"] == [0, 1, 2, 3]


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"mode": "sometimes"}, "JITI mode"),
        ({"threshold_mode": "rel"}, "threshold_mode"),
        ({"window": 0}, "window"),
        ({"n_candidates": 1}, "n_candidates"),
        ({"threshold": -1.0}, "threshold"),
        ({"trigger": "rise"}, "JITI trigger"),
    ],
)
def test_bad_settings_are_user_errors(kwargs, message):
    with pytest.raises(UserInputError, match=message):
        make_jiti(SamplingPolicy(), ScriptedCritic([]), **kwargs)


def test_missing_state_observation_is_a_user_error():
    jiti = make_jiti(SamplingPolicy(), ScriptedCritic([0.0]))
    jiti.reset(META)
    with pytest.raises(UserInputError, match="'state'"):
        jiti({"agentview": np.zeros((2, 2, 3))})


def test_intervened_steps_log_every_candidate_score_and_the_action_change():
    class PreferPositive:
        def bind(self, metadata):
            return self

        def q(self, state, actions):
            return np.asarray(actions)[:, 0]  # prefers a large first action dimension

    jiti = make_jiti(SamplingPolicy(), PreferPositive(), mode="always", n_candidates=8)
    rollout(jiti, 3)
    trace = jiti.trace()
    assert trace["intervened"] == [True, True, True]
    for cand, chosen, chosen_q, change in zip(
        trace["candidate_q"], trace["chosen"], trace["chosen_q"], trace["action_change"]
    ):
        assert len(cand) == 8 and chosen == int(np.argmax(cand)) and abs(chosen_q - max(cand)) < 1e-3
        assert (change > 0) == (chosen != 0)


def test_trust_radius_keeps_far_candidates_out_of_the_choice():
    class PreferPositive:
        def bind(self, metadata):
            return self

        def q(self, state, actions):
            return np.asarray(actions)[:, 0]

    free = make_jiti(SamplingPolicy(), PreferPositive(), mode="always", n_candidates=8, seed=1)
    near = make_jiti(SamplingPolicy(), PreferPositive(), mode="always", n_candidates=8, seed=1, trust_radius=1e-9)
    rollout(free, 3), rollout(near, 3)
    assert all(d.chosen == 0 and d.action_change == 0.0 for d in near.log)  # only the base action is near enough
    assert any(d.chosen != 0 for d in free.log)
    with pytest.raises(UserInputError, match="trust_radius"):
        make_jiti(SamplingPolicy(), PreferPositive(), trust_radius=0.0)


def test_min_gain_keeps_the_base_action_unless_the_best_candidate_beats_it_by_more():
    # candidates score base_q + k / 100: the best of 16 gains 0.15 over the base action
    small = make_jiti(SamplingPolicy(), ScriptedCritic([5.0] * 4), mode="always", min_gain=0.1)
    large = make_jiti(SamplingPolicy(), ScriptedCritic([5.0] * 4), mode="always", min_gain=0.2)
    rollout(small, 4), rollout(large, 4)
    assert [d.chosen for d in small.log] == [15] * 4
    assert [d.chosen for d in large.log] == [0] * 4 and all(d.chosen_q == 5.0 for d in large.log)
    assert large.config()["min_gain"] == 0.2
    with pytest.raises(UserInputError, match="min_gain"):
        make_jiti(SamplingPolicy(), ScriptedCritic([]), min_gain=-0.1)


class TiltedCritic(ScriptedCritic):
    """Q(s, a) = base_q[t] + tilt * a[0] + bump at candidate row `bumped` (a[0] = bumped / 100)."""

    def __init__(self, base_q, tilt, bumped=None, bump=0.0):
        super().__init__(base_q)
        self.tilt, self.bumped, self.bump = tilt, bumped, bump

    def q(self, state, actions):
        first = np.asarray(actions)[:, 0]
        bonus = np.where(np.isclose(first, (self.bumped or 0) / 100.0) & (self.bumped is not None), self.bump, 0.0)
        return self.base_q[int(state[0])] + self.tilt * first + bonus


def test_an_ensemble_overrides_only_with_every_members_agreement_and_picks_the_best_mean():
    from critics import CriticEnsemble

    # both members prefer higher a[0] (the second member half as much, with a bump at candidate 3): best mean is 15
    agree = CriticEnsemble([TiltedCritic([5.0] * 3, 1.0), TiltedCritic([7.0] * 3, 0.5, bumped=3, bump=0.05)])
    jiti = make_jiti(SamplingPolicy(), agree, mode="always")
    rollout(jiti, 3)
    assert [d.chosen for d in jiti.log] == [15] * 3
    assert jiti.log[0].q == pytest.approx(6.0) and jiti.log[0].chosen_q == pytest.approx(6.0 + 0.75 * 0.15)
    # one member prefers lower a[0] except for a bump at candidate 3: only candidate 3 has both votes
    split = CriticEnsemble([TiltedCritic([5.0] * 3, 1.0), TiltedCritic([5.0] * 3, -1.0, bumped=3, bump=0.5)])
    jiti = make_jiti(SamplingPolicy(), split, mode="always")
    rollout(jiti, 3)
    assert [d.chosen for d in jiti.log] == [3] * 3
    # without the bump no candidate has both votes: the base action stays, though the mean is flat
    against = CriticEnsemble([TiltedCritic([5.0] * 3, 1.0), TiltedCritic([5.0] * 3, -1.0)])
    jiti = make_jiti(SamplingPolicy(), against, mode="always")
    rollout(jiti, 3)
    assert [d.chosen for d in jiti.log] == [0] * 3 and jiti.log[0].candidate_q == [5.0] * 16


def test_max_overrides_stops_intervening_once_the_episode_spent_its_budget():
    """Only executed alternatives count: interventions that keep the base plan do not spend the budget,
    and a new episode starts with a full one."""
    climb = [float(t) for t in range(12)] + [3.0]  # the deviation trigger fires at decisions 4 to 12
    capped = make_jiti(SamplingPolicy(), ScriptedCritic(climb), window=4, threshold=1.0, max_overrides=3)
    for _ in range(2):
        rollout(capped, 13)
        assert [d.step for d in capped.log if d.intervened] == [4, 5, 6] and capped.overrides == 3
        assert all(d.chosen == 15 for d in capped.log if d.intervened)
    kept = make_jiti(SamplingPolicy(), TiltedCritic(climb, -1.0), window=4, threshold=1.0, max_overrides=3)
    rollout(kept, 13)  # every candidate scores below the base plan: it stays, and nothing is spent
    assert [d.step for d in kept.log if d.intervened] == list(range(4, 13)) and kept.overrides == 0
    assert capped.config()["max_overrides"] == 3
    with pytest.raises(UserInputError, match="max_overrides"):
        make_jiti(SamplingPolicy(), ScriptedCritic([]), max_overrides=-1)


def test_an_ensemble_refuses_a_single_member_or_mixed_chunk_lengths():
    from critics import CriticEnsemble

    with pytest.raises(UserInputError, match="at least 2"):
        CriticEnsemble([ScriptedCritic([])])
    chunked = ChunkCritic([])
    with pytest.raises(UserInputError, match="chunks of one length"):
        CriticEnsemble([ScriptedCritic([]), chunked])


class ChunkPolicy:
    """Decides 3 actions at a time: row i of a plan is BASE with a[1] = i / 10 (its place in the chunk);
    candidate k of `sample_plans` has a[0] = k / 100 on every row. Records where it planned and observed."""

    chunk = 3

    def __init__(self):
        self.planned, self.observed = [], []

    def __call__(self, obs):
        raise AssertionError("JITI drives a chunked policy through plan and observe")

    def _plan(self):
        plan = np.repeat(BASE[None], self.chunk, axis=0)
        plan[:, 1] = np.arange(self.chunk) / 10.0
        return plan

    def plan(self, obs):
        self.planned.append(int(obs["state"][0]))
        return self._plan()

    def sample_plans(self, obs, n):
        out = np.repeat(self._plan()[None], n, axis=0)
        out[:, :, 0] = (np.arange(n) / 100.0)[:, None]
        return out

    def sample(self, obs, n):
        return self.sample_plans(obs, n)[:, 0]

    def observe(self, obs):
        self.observed.append(int(obs["state"][0]))

    def reset(self, metadata=None, *, seed=None):
        self.planned, self.observed = [], []


class ChunkCritic(ScriptedCritic):
    """Q(s, chunk) = base_q[t] + the chunk's first entry (a[0] of its first action)."""

    chunk = 3


def test_a_chunked_policy_is_decided_once_per_chunk_and_observed_in_between():
    policy = ChunkPolicy()
    jiti = make_jiti(policy, ChunkCritic([5.0] * 12), window=3, threshold=0.5)
    actions = rollout(jiti, 12)
    assert policy.planned == [0, 3, 6, 9] and policy.observed == [1, 2, 4, 5, 7, 8, 10, 11]
    assert [d.step for d in jiti.log] == [0, 3, 6, 9] and jiti.interventions == 0
    assert [a[1] for a in actions] == pytest.approx([0.0, 0.1, 0.2] * 4)  # each plan executed in order
    assert jiti.critic.batches[0].shape == (1, 21)  # the critic scores the whole chunk, flattened


def test_an_intervention_replaces_the_whole_chunk():
    q = [5.0] * 12
    q[9] = 8.0  # the jump is seen at the decision of step 9
    jiti = make_jiti(ChunkPolicy(), ChunkCritic(q), window=3, threshold=0.5, n_candidates=16)
    actions = rollout(jiti, 12)
    assert [d.step for d in jiti.log if d.intervened] == [9]
    assert jiti.log[-1].chosen == 15 and jiti.log[-1].action_change == pytest.approx(0.15)
    assert [a[0] for a in actions[9:]] == pytest.approx([0.15] * 3)  # all three steps of candidate 15
    assert [a[1] for a in actions[9:]] == pytest.approx([0.0, 0.1, 0.2])
    assert [a[0] for a in actions[:9]] == pytest.approx([0.0] * 9)


def test_a_critic_of_another_chunk_length_is_refused():
    with pytest.raises(UserInputError, match="chunks of 1 actions but the policy decides 3.*--chunk 3"):
        make_jiti(ChunkPolicy(), ScriptedCritic([5.0]))
    with pytest.raises(UserInputError, match="chunks of 3 actions but the policy decides 1"):
        make_jiti(SamplingPolicy(), ChunkCritic([5.0]))


def test_plan_distance_is_the_rms_over_the_chunk_of_the_per_step_distance():
    candidates = np.zeros((3, 2, 7))
    candidates[1, 0, 0] = 1.0  # one step moved by 1, the other not
    candidates[2, :, :2] = 0.6  # both steps moved by 0.6 * sqrt(2)
    assert plan_distance(candidates) == pytest.approx([0.0, np.sqrt(0.5), 0.6 * np.sqrt(2)])
    assert plan_distance(candidates[:, :1]) == pytest.approx([0.0, 1.0, 0.6 * np.sqrt(2)])  # chunk 1: plain L2


def test_mode_random_intervenes_at_the_requested_rate_with_eligible_candidates_only():
    policy = SamplingPolicy()  # candidate k has a[0] = k / 100: candidates 1..10 lie within 0.1 of the base
    jiti = make_jiti(policy, None, mode="random", random_rate=0.3, trust_radius=0.1, n_candidates=16, seed=5)
    actions = rollout(jiti, 400)
    hit = [d for d in jiti.log if d.intervened]
    assert 0.2 < len(hit) / 400 < 0.4 and all(d.q is None and d.candidate_q is None for d in jiti.log)
    assert {d.chosen for d in hit} == set(range(1, 11))  # never the base, never beyond the trust radius
    assert all(actions[d.step][0] == pytest.approx(d.chosen / 100.0) for d in hit)
    again = make_jiti(SamplingPolicy(), None, mode="random", random_rate=0.3, trust_radius=0.1, n_candidates=16, seed=5)
    assert [a.tolist() for a in rollout(again, 400)] == [a.tolist() for a in actions]  # seeded
    scored = make_jiti(SamplingPolicy(), ScriptedCritic([5.0] * 400), mode="random", random_rate=0.3, seed=5)
    rollout(scored, 400)
    assert all(d.q == 5.0 for d in scored.log) and all(len(d.candidate_q) == 16 for d in scored.log if d.intervened)
    with pytest.raises(UserInputError, match="random_rate"):
        make_jiti(SamplingPolicy(), None, mode="random", random_rate=1.5)


def test_mode_random_with_random_steps_intervenes_exactly_there():
    jiti = make_jiti(
        ChunkPolicy(), None, mode="random", random_rate=1.0, random_steps=[3, 7, 9], n_candidates=16, seed=5
    )
    rollout(jiti, 12)
    # decisions come every 3 steps: step 7 lies inside a chunk and is no decision, so never explored
    assert [d.step for d in jiti.log if d.intervened] == [3, 9] and all(d.chosen != 0 for d in jiti.log if d.intervened)
    # rollouts choose the branch step per episode, through reset; the agent's own steps stay for the next
    jiti.reset(META, seed=0, random_steps={6})
    [jiti({"state": np.array([float(t)])}) for t in range(12)]
    assert [d.step for d in jiti.log if d.intervened] == [6]
    rollout(jiti, 12)
    assert [d.step for d in jiti.log if d.intervened] == [3, 9]
    with pytest.raises(AttributeError):
        jiti.mode = "jiti"  # the agent's settings never change during a run


def test_a_steered_warmup_reselects_the_decisions_before_the_window_is_full_and_then_only_critical_ones():
    """warmup="steer": the first `window` decisions choose like `always` (no fluctuation can be measured
    yet), then the trigger alone decides; the default "base" executes the base plan while warming up.
    The chosen candidates' scores fill the window, so the reference is the steered trajectory's level."""
    q = [5.0] * 20
    q[12] = 1.0  # a drop: critical at decision 12 either way
    steered = make_jiti(SamplingPolicy(), ScriptedCritic(q), window=4, threshold=1.0, trigger="drop", warmup="steer")
    actions = rollout(steered, 20)
    assert [d.step for d in steered.log if d.intervened] == [0, 1, 2, 3, 12]
    assert [d.chosen for d in steered.log[:4]] == [15] * 4 and actions[0][0] == pytest.approx(0.15)
    assert steered.log[4].mean == pytest.approx(5.15) and steered.config()["warmup"] == "steer"
    plain = make_jiti(SamplingPolicy(), ScriptedCritic(q), window=4, threshold=1.0, trigger="drop")
    rollout(plain, 20)
    assert [d.step for d in plain.log if d.intervened] == [12] and plain.config()["warmup"] == "base"
    # the override budget bounds the steered warm-up too, and modes other than jiti ignore the setting
    capped = make_jiti(
        SamplingPolicy(), ScriptedCritic(q), window=4, threshold=1.0, trigger="drop", warmup="steer", max_overrides=2
    )
    rollout(capped, 20)
    assert [d.step for d in capped.log if d.intervened] == [0, 1]
    base = make_jiti(SamplingPolicy(), ScriptedCritic(q), window=4, mode="base", warmup="steer")
    rollout(base, 20)
    assert base.interventions == 0
    with pytest.raises(UserInputError, match="warmup"):
        make_jiti(SamplingPolicy(), ScriptedCritic([]), warmup="always")


def test_trigger_none_steers_only_the_warmup_and_refuses_to_run_as_a_silent_base_policy():
    q = [5.0] * 20
    q[12] = -50.0  # a drop any threshold would call critical
    warm_only = make_jiti(SamplingPolicy(), ScriptedCritic(q), window=4, threshold=1.0, trigger="none", warmup="steer")
    rollout(warm_only, 20)
    assert [d.step for d in warm_only.log if d.intervened] == [0, 1, 2, 3]
    assert warm_only.log[12].q == pytest.approx(-50.0) and warm_only.log[12].chosen == 0
    with pytest.raises(UserInputError, match="trigger 'none' never intervenes"):
        make_jiti(SamplingPolicy(), ScriptedCritic(q), trigger="none")
    make_jiti(SamplingPolicy(), ScriptedCritic(q), trigger="none", mode="always")  # other modes ignore the trigger


class FreshSamplesPolicy:
    """A policy whose `sample` draws never include its base action (as `BCPolicy.sample_plans` draws fresh
    plans): JITI itself must put the base plan among the candidates."""

    def __call__(self, obs):
        return BASE.copy()

    def sample(self, obs, n):
        out = np.repeat(BASE[None], n, axis=0)
        out[:, 1] = 0.5 + np.arange(n) / 100.0  # every draw differs from BASE (whose entry 1 is 0.1)
        return out

    def reset(self, metadata=None, *, seed=None):
        pass


class ChunkedFreshSamplesPolicy:
    """The chunked version: `plan` is the base chunk, `sample_plans` fresh chunks that all differ from it."""

    chunk = 3

    def __init__(self):
        self._queue = []

    def plan(self, obs):
        return np.repeat(BASE[None], self.chunk, axis=0)

    def sample_plans(self, obs, n):
        out = np.repeat(self.plan(obs)[None], n, axis=0)
        out[:, :, 1] = 0.5 + np.arange(n)[:, None] / 100.0
        return out

    def observe(self, obs):
        pass

    def __call__(self, obs):
        return BASE.copy()

    def sample(self, obs, n):
        return self.sample_plans(obs, n)[:, 0]

    def reset(self, metadata=None, *, seed=None):
        pass


class PrefersBaseCritic:
    """Q = minus the distance of entry 1 of every action to the base action's: the base plan scores best.
    Remembers every batch it scored (flattened plans)."""

    def __init__(self, chunk=1):
        self.chunk, self.batches = chunk, []

    def bind(self, metadata):
        pass

    def q(self, state, actions):
        actions = np.asarray(actions).reshape(len(actions), self.chunk, 7)
        self.batches.append(actions)
        return -np.abs(actions[:, :, 1] - BASE[1]).sum(-1)


@pytest.mark.parametrize("chunked", [False, True])
def test_the_base_plan_is_always_candidate_zero_even_when_the_policy_never_samples_it(chunked):
    policy = ChunkedFreshSamplesPolicy() if chunked else FreshSamplesPolicy()
    chunk = 3 if chunked else 1
    critic = PrefersBaseCritic(chunk)
    jiti = make_jiti(policy, critic, mode="always", n_candidates=8)
    actions = rollout(jiti, 4 * chunk)
    assert len(critic.batches) == 4 and all(len(b) == 8 for b in critic.batches)
    for batch in critic.batches:  # every scored batch holds the full candidate set, the base plan first
        np.testing.assert_array_equal(batch[0], np.repeat(BASE[None], chunk, axis=0))
    # the critic prefers the base plan, so it is what runs, and no decision counts as an override
    assert all(np.array_equal(a, BASE) for a in actions)
    assert [d.chosen for d in jiti.log] == [0] * 4 and jiti.overrides == 0
    # mode "jiti" with a steered warm-up re-ranks its first decisions the same way
    steered = make_jiti(policy, PrefersBaseCritic(chunk), window=2, trigger="none", warmup="steer", n_candidates=8)
    actions = rollout(steered, 2 * chunk)
    assert [d.intervened for d in steered.log] == [True, True] and [d.chosen for d in steered.log] == [0, 0]
    assert all(np.array_equal(a, BASE) for a in actions)


@pytest.mark.parametrize("trigger", ["deviation", "drop"])
def test_a_deviation_equal_to_an_absolute_threshold_is_not_critical(trigger):
    """dq > tau is critical, dq == tau is not, for either trigger (the drop trigger reads a fall)."""
    sign = 1.0 if trigger == "deviation" else -1.0
    for last, critical in ((5.0 + sign * 1.0, False), (5.0 + sign * 1.25, True)):
        jiti = make_jiti(SamplingPolicy(), ScriptedCritic([5.0] * 4 + [last]), window=4, threshold=1.0, trigger=trigger)
        rollout(jiti, 5)
        d = jiti.log[4]
        assert d.tau == 1.0 and d.dq == pytest.approx(abs(last - 5.0)) and d.intervened is critical


class DensityPolicy(SamplingPolicy):
    """SamplingPolicy with a log-density that peaks at a[0] = `peak` (it never sees the base plan's own)."""

    def __init__(self, peak):
        super().__init__()
        self.peak, self.scored = peak, []

    def log_prob_plans(self, obs, plans):
        self.scored.append(np.array(plans))
        return -((np.asarray(plans)[:, 0, 0] - self.peak) ** 2)


def test_mode_likelihood_executes_the_policys_most_probable_eligible_candidate_without_a_critic():
    policy = DensityPolicy(peak=0.05)  # candidate k has a[0] = k / 100: candidate 5 is the most probable
    jiti = make_jiti(policy, None, mode="likelihood", n_candidates=16)
    actions = rollout(jiti, 6)
    assert all(d.intervened and d.chosen == 5 and d.q is None for d in jiti.log)
    assert all(a[0] == pytest.approx(0.05) for a in actions) and policy.scored[0].shape == (16, 1, 7)
    far = make_jiti(DensityPolicy(peak=0.12), None, mode="likelihood", trust_radius=0.1, n_candidates=16)
    rollout(far, 3)
    assert [d.chosen for d in far.log] == [10, 10, 10]  # the most probable within the radius, not candidate 12
    at_base = make_jiti(DensityPolicy(peak=-0.5), None, mode="likelihood", n_candidates=16)
    rollout(at_base, 3)
    assert [d.chosen for d in at_base.log] == [0, 0, 0]  # the base plan when it is the most probable


def test_mode_likelihood_refuses_a_policy_that_has_no_density_in_one_line():
    with pytest.raises(UserInputError, match=r"mode 'likelihood' needs a base policy with log_prob_plans"):
        make_jiti(SamplingPolicy(), None, mode="likelihood")


def test_mode_consensus_executes_the_candidate_nearest_the_candidates_mean():
    jiti = make_jiti(SamplingPolicy(), None, mode="consensus", n_candidates=15)
    actions = rollout(jiti, 4)
    # a[0] runs 0.00 .. 0.14 with the base plan 0.0 among them: the mean is candidate 7's 0.07
    assert [d.chosen for d in jiti.log] == [7, 7, 7, 7] and actions[0][0] == pytest.approx(0.07)
    near = make_jiti(SamplingPolicy(), None, mode="consensus", trust_radius=0.04, n_candidates=16)
    rollout(near, 2)
    assert [d.chosen for d in near.log] == [2, 2]  # the mean of the eligible 0..4 is candidate 2


def test_a_mode_is_one_registered_object_that_jiti_and_its_config_use():
    from elegant.intervention import modes
    from elegant.intervention.selectors import Choice
    from elegant.intervention.triggers import AtSteps

    class LastCandidate:
        def select(self, choice: Choice) -> int:
            return len(choice.distance) - 1

    mode = modes.JITIMode(
        name="last-at-two",
        help="the last candidate at step 2",
        settings=("n_candidates",),
        trigger=lambda config, steps: AtSteps([2]),
        selector=lambda config: LastCandidate(),
        describe=lambda record, candidates: "test mode",
        needs_critic=False,
    )
    modes.register_mode(mode)
    try:
        jiti = make_jiti(SamplingPolicy(), None, JITIConfig(mode="last-at-two"), n_candidates=5)
        rollout(jiti, 4)
        assert [d.chosen for d in jiti.log] == [0, 0, 4, 0]
        assert jiti.config()["n_candidates"] == 5 and "window" not in jiti.config()  # its settings, no others
        with pytest.raises(UserInputError, match=r"window \(--window\) does nothing in mode 'last-at-two'"):
            JITIConfig(mode="last-at-two").refuse_unused(["window"])
        with pytest.raises(ValueError, match="registered twice"):
            modes.register_mode(mode)
    finally:
        modes._REGISTRY.pop("last-at-two")
    with pytest.raises(UserInputError, match="unknown JITI mode 'last-at-two'; expected one of: always, base"):
        JITIConfig(mode="last-at-two")
