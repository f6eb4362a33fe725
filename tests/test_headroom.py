"""The intervention-headroom diagnostic: its summary arithmetic (unit) and, on the real simulator, that a
branch replays the base episode exactly up to the changed action (the whole method rests on that)."""

import numpy as np
import pytest
from conftest import load_benchmark

from base_suites import make_env
from elegant.intervention.config import JITIConfig
from elegant.policies.adapters import as_policy
from itc import ITCMonitor

headroom = load_benchmark("headroom")
_rollout, branch_episode, summarize_headroom = headroom._rollout, headroom.branch_episode, headroom.summarize_headroom


def _point(q, distance, elegant):
    return {"step": 0, "q": q, "distance": distance, "elegant": elegant}


def test_summary_counts_reachable_critic_and_random_choices_within_the_trust_radius():
    inelegant = {
        "base_elegant": False,
        "points": [
            # candidate 2 is elegant and the critic's best, but too far: the critic picks 1 (not elegant)
            _point([0.0, 1.0, 5.0, 0.5], [0.0, 0.1, 0.9, 0.2], [False, False, True, True]),
            # nothing eligible is elegant
            _point([0.0, 1.0, 2.0], [0.0, 0.1, 0.2], [False, False, False]),
        ],
    }
    elegant = {
        "base_elegant": True,
        "points": [
            _point([0.0, 2.0, 1.0], [0.0, 0.1, 0.1], [True, False, True]),  # the critic spoils it
        ],
    }
    s = summarize_headroom([inelegant, elegant], JITIConfig(trust_radius=0.3))
    assert s["decision_points"] == 3 and s["base_esr"] == 0.5
    assert s["choice_matters"] == pytest.approx(2 / 3)
    assert s["headroom"] == 0.5 and s["rescuable_episodes"] == 1.0
    assert s["critic_hit"] == 0.0
    assert s["random_hit"] == pytest.approx((1 / 3 + 0) / 2)
    assert s["critic_harm"] == 1.0 and s["random_harm"] == pytest.approx(1 / 3)
    # eligible outcomes differ at the first point (the elegant one scored between the two others: 0.5)
    # and on the elegant episode (both elegant ones scored below the spoiling one: 0)
    assert s["outcome_auroc"] == pytest.approx(0.25)
    assert s["outcome_auroc_se"] == pytest.approx(np.std([0.5, 0.0], ddof=1) / np.sqrt(2))
    # without a trust radius the far elegant candidate is the critic's choice; one point has no spread
    alone = summarize_headroom([inelegant], JITIConfig(trust_radius=None))
    assert alone["critic_hit"] == 0.5 and alone["outcome_auroc"] == 0.75 and alone["outcome_auroc_se"] is None


def test_summary_scores_the_critic_free_controls_and_splits_the_auroc_by_what_the_base_episode_needed():
    def plans(*first):  # one-step plans whose first action entry is given, the rest zero
        out = np.zeros((len(first), 1, 7))
        out[:, 0, 0] = first
        return out.tolist()

    # inelegant base: candidate 1 (the most probable) and 3 (nearest the mean 0.225 of 0, 0.1, 0.5, 0.3)
    rescue = _point([0.0, 1.0, 2.0, 0.5], [0.0, 0.1, 0.5, 0.3], [False, True, False, False])
    rescue.update(candidates=plans(0.0, 0.1, 0.5, 0.3), log_prob=[-3.0, -1.0, -2.0, -5.0])
    # elegant base: the policy prefers candidate 2, which spoils it; the mean 0.1 is candidate 1's
    keep = _point([0.0, 2.0, 1.0], [0.0, 0.1, 0.2], [True, True, False])
    keep.update(candidates=plans(0.0, 0.1, 0.2), log_prob=[-2.0, -3.0, -1.0])
    s = summarize_headroom(
        [{"base_elegant": False, "points": [rescue]}, {"base_elegant": True, "points": [keep]}],
        JITIConfig(trust_radius=None),
    )
    assert s["likelihood_hit"] == 1.0 and s["consensus_hit"] == 0.0 and s["critic_hit"] == 0.0
    assert s["likelihood_harm"] == 1.0 and s["consensus_harm"] == 0.0 and s["critic_harm"] == 0.0
    # rescue: the elegant candidate 1 scores 1.0, above two of the three others; harm avoidance: the
    # spoiling candidate 2 scores 1.0, below one of the two elegant ones and above the other
    assert s["rescue_auroc"] == pytest.approx(2 / 3) and s["harm_avoidance_auroc"] == pytest.approx(0.5)
    assert s["likelihood_hit_se"] is None  # one start: no spread to measure


def test_clustered_rate_treats_the_start_as_the_unit():
    rate, se = headroom.clustered_rate([[1.0, 1.0, 0.0], [0.0], [1.0, 0.0]])
    sums, counts = np.array([2.0, 0.0, 1.0]), np.array([3.0, 1.0, 2.0])
    assert rate == pytest.approx(3 / 6)
    assert se == pytest.approx(np.sqrt(3 / 2 * np.sum((sums - 0.5 * counts) ** 2)) / 6)
    assert headroom.clustered_rate([]) == (None, None) and headroom.clustered_rate([[1.0, 0.0]]) == (0.5, None)


class Plunge:
    def __call__(self, obs):
        return np.array([0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0])


class HeightCritic:
    def q(self, state, actions):
        return state[2] - np.abs(np.asarray(actions)[:, 0])


@pytest.mark.sim
def test_a_branch_replays_the_base_episode_exactly_up_to_the_changed_action():
    env = make_env("libero_object", 0, seed=0, max_steps=16)
    monitor, policy = ITCMonitor(env), as_policy(Plunge(), seed=0)
    states = []
    actions, _ = _rollout(
        env, monitor, policy, 1, 3, 7, (), False, lambda t, obs, a: states.append(obs["state"].copy())
    )
    replayed = []
    changed = np.array([0.5, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0])
    _rollout(
        env,
        monitor,
        policy,
        1,
        3,
        7,
        [*actions[:8], changed],
        False,
        lambda t, obs, a: replayed.append(obs["state"].copy()),
    )
    np.testing.assert_array_equal(np.array(replayed[:9]), np.array(states[:9]))  # identical until the change acts
    assert not np.array_equal(replayed[9], states[9])
    result = branch_episode(env, monitor, policy, HeightCritic(), 3, 7, every=5, first=2, n_candidates=3)
    env.close()
    assert [p["step"] for p in result["points"]] == [2, 7, 12]
    for point in result["points"]:
        assert point["distance"][0] == 0.0 and len(point["q"]) == len(point["elegant"]) == 3
        assert point["elegant"][0] == result["base_elegant"] is False  # a plunge into the objects is never elegant


def test_headroom_plot_is_written_and_an_empty_result_is_refused(tmp_path):
    from base_suites import UserInputError

    plot_headroom = headroom.plot_headroom

    result = {
        "episodes": [
            {
                "init_index": 3,
                "base_elegant": False,
                "points": [
                    _point([0.0, 1.0, 5.0], [0.0, 0.1, 0.9], [False, False, True]),
                    _point([2.0, 1.0, 0.0], [0.0, 0.2, 0.1], [False, True, False]),
                ],
            }
        ]
    }
    path = plot_headroom(result, JITIConfig(trust_radius=0.3), tmp_path / "headroom.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(UserInputError):
        plot_headroom(
            {"episodes": [{"init_index": 0, "base_elegant": True, "points": []}]}, JITIConfig(), tmp_path / "empty.png"
        )


class ChunkedPlunge(Plunge):
    """Plunges two actions at a time; its sampled plans drift sideways by the candidate's index."""

    chunk = 2

    def reset(self, metadata=None, *, seed=None):
        self.observed = 0

    def plan(self, obs):
        return np.repeat(self(obs)[None], 2, axis=0)

    def sample_plans(self, obs, n):
        plans = np.repeat(self.plan(obs)[None], n, axis=0)
        plans[:, :, 0] = (np.arange(n) / 4.0)[:, None]
        return plans

    def sample(self, obs, n):
        return self.sample_plans(obs, n)[:, 0]

    def observe(self, obs):
        self.observed += 1


class ChunkHeightCritic:
    chunk = 2

    def bind(self, metadata):
        pass

    def q(self, state, chunks):
        return state[2] - np.abs(np.asarray(chunks)[:, 0])


class ContraryChunkCritic(ChunkHeightCritic):
    def q(self, state, chunks):
        return -super().q(state, chunks)


@pytest.mark.sim
def test_a_chunked_policy_is_branched_on_whole_chunks_at_its_decision_points():
    from base_suites import UserInputError

    intervention_headroom = headroom.intervention_headroom

    env = make_env("libero_object", 0, seed=0, max_steps=12)
    monitor, policy = ITCMonitor(env), ChunkedPlunge()
    result = branch_episode(env, monitor, policy, ChunkHeightCritic(), 3, 7, every=4, first=2, n_candidates=3)
    assert [p["step"] for p in result["points"]] == [2, 6]  # step 10's chunk would end the episode
    assert policy.observed > 0  # the policy saw the steps inside its chunks
    for point in result["points"]:
        assert point["distance"] == pytest.approx([0.0, 0.25, 0.5])  # whole chunks moved sideways
    actions, _ = _rollout(
        env, monitor, policy, 2, 3, 7, [np.zeros(7)] * 2 + list(ChunkedPlunge().sample_plans(None, 3)[2]), False
    )
    env.close()
    assert [a[0] for a in actions[:6]] == [0.0, 0.0, 0.5, 0.5, 0.0, 0.0]  # the candidate chunk, then the policy again
    with pytest.raises(UserInputError, match="multiples of 2"):
        intervention_headroom(
            "libero_object", 0, ChunkedPlunge(), ChunkHeightCritic(), every=3, first=2, jiti=JITIConfig()
        )
    _another_critic_is_judged_on_the_stored_branches(result)
    with pytest.raises(UserInputError, match="chunks of 1 actions but the policy decides 2"):
        intervention_headroom("libero_object", 0, ChunkedPlunge(), HeightCritic(), every=4, first=2, jiti=JITIConfig())


def _another_critic_is_judged_on_the_stored_branches(episode):
    """rescore_headroom recomputes Q from each point's stored state and candidates; outcomes stay."""
    from base_suites import UserInputError

    rescore_headroom = headroom.rescore_headroom

    result = {"suite": "libero_object", "task": 0, "chunk": 2, "episodes": [episode]}
    rescored = rescore_headroom(result, ContraryChunkCritic(), JITIConfig(trust_radius=None))
    for old, new in zip(episode["points"], rescored["episodes"][0]["points"]):
        assert new["q"] == pytest.approx([-v for v in old["q"]], abs=1e-3)
        assert new["elegant"] == old["elegant"] and new["candidates"] == old["candidates"]
    assert rescored["summary"]["decision_points"] == 2
    with pytest.raises(UserInputError, match="chunks of 1 actions but the policy decides 2"):
        rescore_headroom(result, HeightCritic(), JITIConfig(trust_radius=None))
    stripped = {
        **result,
        "episodes": [
            {**episode, "points": [{k: v for k, v in p.items() if k != "candidates"} for p in episode["points"]]}
        ],
    }
    with pytest.raises(UserInputError, match="stores no states and candidates"):
        rescore_headroom(stripped, ContraryChunkCritic(), JITIConfig(trust_radius=None))
