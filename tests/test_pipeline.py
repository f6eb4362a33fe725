"""The chain behind `elegant quickstart` and the effect benchmark, at tiny sizes on the real simulator."""

import json
import os
import shutil
from dataclasses import replace

import pytest

from base_suites import UserInputError
from base_suites.runtime.settings import with_overrides
from critics.config import TrainConfig
from elegant.chain_config import ChainConfig
from elegant.diagnostics.branch_ranking import branch_ranking
from elegant.evaluation.config import EvalConfig
from elegant.evaluation.runner import open_critic, open_policy
from elegant.intervention.config import JITIConfig
from elegant.pipeline import run_chain
from elegant.policies import as_policy
from elegant.policies.bc_config import BCConfig

pytestmark = pytest.mark.sim

# tiny sizes, and the stages these tests were written against (the defaults are the recipe's): a per-step
# policy without input noise, a Cal-QL critic on window penalties, JITI's deviation trigger
TINY = ChainConfig(
    suites=("libero_object",),
    tasks=(0,),
    demos=2,
    successful_only=False,
    policy=BCConfig(epochs=1, chunk=1, obs_noise=0.0),
    critic_rollouts=0,
    critic=TrainConfig(
        steps=20,
        gamma=0.9,
        cql_weight=0.2,
        reward="segment",
        backup="policy",
        hidden=[256, 256],
        weight_decay=0.0,
        mc_weight=0.0,
        value_loss="mse",
    ),
    critic_members=1,
    modes=("base", "jiti"),
    evaluation=EvalConfig(
        episodes=1,
        max_steps=15,
        jiti=JITIConfig(
            trust_radius=0.3, threshold=2.0, threshold_mode="std", window=10, trigger="deviation", warmup="base"
        ),
    ),
    jiti_gate=False,
)


def tiny(**changes) -> ChainConfig:
    """TINY with `changes`, nested like the config ({"critic": {"steps": 3}})."""
    return with_overrides(TINY, changes)


def copy_data_and_policy(source: str, target) -> None:
    """Start a chain directory from another's demos and policy (their steps are then skipped)."""
    for name in ("demos_libero_object.hdf5", "annotated_libero_object.hdf5"):
        shutil.copy(os.path.join(source, name), os.path.join(target, name))
    shutil.copytree(os.path.join(source, "policy"), os.path.join(target, "policy"))


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    out = str(tmp_path_factory.mktemp("chain"))
    return out, run_chain(out, TINY, progress=False)


def test_chain_runs_every_step_and_reports_the_eval_numbers(chain):
    out, result = chain
    for name in (
        "demos_libero_object.hdf5",
        "annotated_libero_object.hdf5",
        "critic/critic.json",
        "policy/config.json",
    ):
        assert os.path.exists(os.path.join(out, name)), name
    assert os.path.exists(result["report"])
    for mode in ("base", "jiti"):
        summary = json.load(open(os.path.join(result["runs"][mode]["libero_object"], "summary.json")))
        assert summary["config"]["max_steps"] == 15 and summary["episodes"] == 1
        for key in ("success_rate", "esr", "interventions_per_episode"):
            assert result[mode][key] == pytest.approx(summary[key])
            assert result["per_suite"]["libero_object"][mode][key] == pytest.approx(summary[key])
    jiti = json.load(open(os.path.join(result["runs"]["jiti"]["libero_object"], "config.json")))
    assert jiti["jiti"]["trust_radius"] == TINY.evaluation.jiti.trust_radius
    chain_json = json.load(open(os.path.join(out, "chain.json")))
    assert chain_json["format"] == "libero-elegant-chain/3" and chain_json["settings"]["critic"]["steps"] == 20


def test_the_chain_ends_with_a_summary_that_agrees_with_its_report(chain):
    from elegant.pipeline import effects_text
    from elegant.reporting.report import compare_runs

    out, result = chain
    runs = result["runs"]
    effects = result["effects"]["libero_object"]
    paired = compare_runs([runs["base"]["libero_object"], runs["jiti"]["libero_object"]])["paired"][0]["elegant"]
    jiti = effects["jiti"]
    assert (jiti["made_elegant"], jiti["spoiled"]) == (paired["only_after"], paired["only_before"])
    assert effects["jiti"]["p_value"] == paired["p_value"] and effects["base"]["esr"] == result["base"]["esr"]
    text = effects_text(result)
    assert f"{effects['jiti']['made_elegant']} made elegant, {effects['jiti']['spoiled']} spoiled" in text
    assert text.endswith(f"report: {result['report']}") and "starts" in text.splitlines()[0]


def test_chain_resumes_without_redoing_and_refuses_other_settings(chain):
    out, result = chain
    critic = os.path.join(out, "critic", "critic.json")
    before = os.path.getmtime(critic)
    again = run_chain(out, TINY, progress=False)
    assert os.path.getmtime(critic) == before
    assert {m: again[m] for m in ("base", "jiti")} == {m: result[m] for m in ("base", "jiti")}
    with pytest.raises(UserInputError, match="other settings \\(critic.steps, demos\\)"):
        run_chain(out, tiny(demos=3, critic={"steps": 21}), progress=False)
    with pytest.raises(UserInputError, match="chain modes"):
        run_chain(out, tiny(modes=("sometimes",)), progress=False)
    with pytest.raises(UserInputError, match="chain policy settings: train_policy: obs_noise must be >= 0"):
        run_chain(out, tiny(policy={"obs_noise": -0.1}), progress=False)
    with pytest.raises(UserInputError, match="unknown policy act 'mean'; expected one of: mode, sample"):
        tiny(evaluation={"policy_act": "mean"})
    with pytest.raises(UserInputError, match="settings: field 'critic.seed' is set by the config that holds it"):
        tiny(critic={"seed": 4})
    with pytest.raises(UserInputError, match="chain: critic.chunk is set by the chain itself"):
        run_chain(out, replace(TINY, critic=replace(TINY.critic, chunk=4)), progress=False)


def test_a_base_only_chain_trains_no_critic(chain, tmp_path):
    """The policy benchmark's chain: the data and policy steps are skipped when their outputs exist, and
    with the base mode alone no critic is trained and the evaluation runs without one."""
    copy_data_and_policy(chain[0], tmp_path)
    result = run_chain(str(tmp_path), tiny(modes=("base",)), progress=False)
    assert not os.path.exists(tmp_path / "critic")
    summary = json.load(open(os.path.join(result["runs"]["base"]["libero_object"], "summary.json")))
    assert summary["config"]["critic"] is None and summary["episodes"] == 1
    assert set(result) >= {"base", "per_suite"} and "jiti" not in result


def test_a_chain_can_evaluate_its_policy_acting_by_draws_from_the_mixture(chain, tmp_path):
    """`policy_act="sample"` reaches the evaluation: the trained policy acts by seeded draws on the real
    simulator, so the same chain run twice gives the same episodes."""
    copy_data_and_policy(chain[0], tmp_path)
    result = run_chain(str(tmp_path), tiny(modes=("base",), evaluation={"policy_act": "sample"}), progress=False)
    run = result["runs"]["base"]["libero_object"]
    assert json.load(open(os.path.join(run, "config.json")))["policy_act"] == "sample"
    traces = os.path.join(run, "traces")
    first = [json.load(open(os.path.join(traces, name)))["segments"] for name in sorted(os.listdir(traces))]
    shutil.rmtree(run)
    again = run_chain(str(tmp_path), tiny(modes=("base",), evaluation={"policy_act": "sample"}), progress=False)
    assert again["base"] == result["base"]
    assert [json.load(open(os.path.join(traces, name)))["segments"] for name in sorted(os.listdir(traces))] == first


def test_a_chain_with_rollouts_trains_the_critic_on_them_and_evaluates_on_other_starts(chain, tmp_path):
    """With `critic_rollouts` the trained policy's episodes, branching at one of `rollout_explore_at`, are
    recorded from the first half of the init states, annotated and added to the critic's data, trained
    with the chain's critic settings; every mode is then evaluated from the second half only. With
    `jiti_gate` base, JITI and `always` are first validated on the rollouts' half, and the JITI evaluation is gated."""
    import h5py

    copy_data_and_policy(chain[0], tmp_path)
    cfg = tiny(
        critic_rollouts=2,
        rollout={"explore_at": (4, 8)},
        critic={
            "backup": "dataset",
            "reward": "elegant",
            "value_loss": "bce",
            "hidden": [16, 16],
            "weight_decay": 0.1,
            "mc_weight": 10.0,
            "explored_fraction": 0.5,
        },
        evaluation={"jiti": {"trust_radius": None, "trigger": "drop"}},
        jiti_gate=True,
        modes=("base", "always", "jiti"),
    )
    result = run_chain(str(tmp_path), cfg, progress=False)
    rollouts = str(tmp_path / "rollouts_libero_object.hdf5")
    training = json.load(open(tmp_path / "critic" / "critic.json"))["training"]
    assert {
        k: training[k]
        for k in ("backup", "reward", "value_loss", "hidden", "weight_decay", "mc_weight", "explored_fraction")
    } == {
        "backup": "dataset",
        "reward": "elegant",
        "value_loss": "bce",
        "hidden": [16, 16],
        "weight_decay": 0.1,
        "mc_weight": 10.0,
        "explored_fraction": 0.5,
    }
    assert [os.path.basename(p) for p in training["paths"]] == [
        "annotated_libero_object.hdf5",
        "annotated_rollouts_libero_object.hdf5",
    ]
    with h5py.File(rollouts) as f:
        starts = sorted(int(f["data"][d].attrs["init_state_index"]) for d in f["data"])
        explored = [json.loads(f["data"][d].attrs["explored_steps"]) for d in f["data"]]
    assert len(starts) == 2 and max(starts) < 25
    assert explored == [[4], [4]]  # the two starts branch at the first point before any start branches at the second
    # rank-check replays the real policy (its history window) through the recorded steps before the branch
    ranked = branch_ranking(
        str(tmp_path / "annotated_rollouts_libero_object.hdf5"),
        as_policy(open_policy(str(tmp_path / "policy")), seed=0),
        open_critic(str(tmp_path / "critic")),
    )
    assert (ranked["all"]["episodes"], ranked["all"]["skipped"]) == (2, 0)
    for mode in ("base", "jiti"):
        config = json.load(open(os.path.join(result["runs"][mode]["libero_object"], "config.json")))
        assert config["init_states"] == list(range(25, 50))
    jiti_config = json.load(open(os.path.join(result["runs"]["jiti"]["libero_object"], "config.json")))
    assert jiti_config["jiti"]["trigger"] == "drop"
    gate = json.load(open(tmp_path / "gate_libero_object.json"))
    assert gate["init_states"] == list(range(25)) and gate["tasks"]["libero_object/0"]["episodes"] == 1
    assert jiti_config["gate"]["modes"] == {"libero_object/0": gate["tasks"]["libero_object/0"]["mode"]}
    assert gate["always_run"] == str(tmp_path / "validate_always_libero_object") and gate["budget"] == 0.4
    for mode in ("base", "jiti", "always"):
        assert json.load(open(tmp_path / f"validate_{mode}_libero_object" / "config.json"))["init_states"] == list(
            range(25)
        )
    with pytest.raises(UserInputError, match="jiti_gate validates on the rollouts' starts"):
        run_chain(str(tmp_path / "other"), tiny(jiti_gate=True), progress=False)
    with pytest.raises(UserInputError, match="unknown JITI trigger 'rise'"):
        with_overrides(cfg, {"evaluation": {"jiti": {"trigger": "rise"}}})
    with pytest.raises(UserInputError, match="chain critic settings: unknown train-critic backup .mine."):
        run_chain(str(tmp_path / "other"), with_overrides(cfg, {"critic": {"backup": "mine"}}), progress=False)
    with pytest.raises(UserInputError, match="chain critic settings: .*value_loss 'bce' needs"):
        run_chain(str(tmp_path / "other"), with_overrides(cfg, {"critic": {"reward": "segment"}}), progress=False)
    with pytest.raises(UserInputError, match="critic.explored_fraction needs explored decisions"):
        run_chain(str(tmp_path / "other"), with_overrides(cfg, {"critic_rollouts": 0}), progress=False)
    with pytest.raises(UserInputError, match="--explore-at needs decision steps >= 0"):
        with_overrides(cfg, {"rollout": {"explore_at": (-8,)}})
    assert not os.path.exists(tmp_path / "other")  # refused before anything was written
    with pytest.raises(UserInputError, match="other settings \\(critic_rollouts\\)"):
        run_chain(str(tmp_path), with_overrides(cfg, {"critic_rollouts": 3}), progress=False)


def test_a_chain_with_critic_members_trains_each_on_its_resample_and_judges_with_all(chain, tmp_path):
    """`critic_members` > 1: members `critic_1` .. `critic_K`, member k trained on bootstrap resample
    seed + k, and the JITI run is judged by all of them together, within its `max_overrides` budget and
    with its `warmup` and number of `candidates`."""
    copy_data_and_policy(chain[0], tmp_path)
    result = run_chain(
        str(tmp_path),
        tiny(critic_members=2, seed=3, evaluation={"jiti": {"max_overrides": 1, "warmup": "steer", "n_candidates": 5}}),
        progress=False,
    )
    assert not os.path.exists(tmp_path / "critic")
    for k, resample in ((1, 3), (2, 4)):
        training = json.load(open(tmp_path / f"critic_{k}" / "critic.json"))["training"]
        assert (training["bootstrap"], training["seed"]) == (resample, resample)
    config = json.load(open(os.path.join(result["runs"]["jiti"]["libero_object"], "config.json")))
    assert (
        config["critic"] == f"{tmp_path / 'critic_1'},{tmp_path / 'critic_2'}" and config["jiti"]["max_overrides"] == 1
    )
    assert config["jiti"]["warmup"] == "steer" and config["jiti"]["n_candidates"] == 5
    with pytest.raises(UserInputError, match="critic_members must be >= 1"):
        run_chain(str(tmp_path / "other"), tiny(critic_members=0), progress=False)
    with pytest.raises(UserInputError, match="unknown JITI warmup"):
        tiny(evaluation={"jiti": {"warmup": "always"}})
    with pytest.raises(UserInputError, match="trigger 'none' never intervenes"):  # refused before any data is made
        tiny(evaluation={"jiti": {"trigger": "none"}})
    with pytest.raises(UserInputError, match="JITI n_candidates must lie in 2..4096"):
        tiny(evaluation={"jiti": {"n_candidates": 1}})
    assert not os.path.exists(tmp_path / "other")


def test_the_quickstart_command_runs_the_recipe_on_every_core_with_its_flags(monkeypatch, tmp_path):
    """`elegant quickstart` hands the recipe configs/quickstart.yaml (chunked policy, branch rollouts, outcome
    critic, steered JITI) to the chain with the flags it was given, on one worker per core unless told otherwise."""
    from base_suites.runtime.compute import ComputeConfig
    from base_suites.runtime.jobs import Workers, available_cores
    from elegant import cli, pipeline
    from elegant.chain_config import load_recipe

    calls = []
    monkeypatch.setattr(
        pipeline,
        "run_chain",
        lambda out, config, progress, workers, compute: (
            calls.append((out, config, workers, compute)) or {"effects": {}, "report": "r"}
        ),
    )
    assert cli.main(["quickstart", "--out", str(tmp_path / "qs"), "--task", "3", "--seed", "2"]) == 0
    assert cli.main(["quickstart", "--out", str(tmp_path / "qs"), "--workers", "1", "--threads", "2"]) == 0
    (out, config, workers, compute), (_, plain, one, two_threads) = calls
    assert compute == ComputeConfig() and two_threads == ComputeConfig(threads=2)
    recipe = load_recipe("quickstart")
    assert (
        out == str(tmp_path / "qs") and (workers, one) == (Workers(available_cores()), Workers(1)) and plain == recipe
    )
    assert config.tasks == (3,) and config.seed == 2 and config.suites == recipe.suites
    assert replace(config, tasks=recipe.tasks, seed=recipe.seed) == recipe
    # the recipe passes the chain's own checks (rollouts for the explored fraction, a steered warm-up)
    config.validate()
    assert config.critic_rollouts > 0 and config.evaluation.jiti.warmup == "steer" and config.policy.chunk > 1
