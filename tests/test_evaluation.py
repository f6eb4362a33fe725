"""The evaluation runner on the real simulator: files, summary numbers, identical starts across modes,
determinism, resume (including a crash-truncated log) and refusal of a different config.

Runs are tiny (1 task, 2 episodes, 20 steps) with the real ITC monitor; the base policy plunges the hand
into the objects, which breaks constraints within 20 steps. The critic stand-in has the `critics`
interface (bind, q(state, actions)); its score falls with the hand's height, so it changes along the
trajectory and JITI with a small threshold does intervene, preferring candidates that drift slightly in x.
"""

import json
import shutil

import numpy as np
import pytest

from base_suites import UserInputError
from base_suites.runtime.jobs import Workers
from elegant.evaluation.runner import episode_start, evaluate
from elegant.intervention.modes import jiti_mode

pytestmark = pytest.mark.sim
SUITE, TASK, STEPS = "libero_object", 0, 20
# the JITI these runs were written against (the defaults are the recipe's); a run gets those its mode uses
JITI_SETTINGS = {
    "window": 3,
    "threshold": 0.02,
    "threshold_mode": "absolute",
    "trigger": "deviation",
    "warmup": "base",
    "trust_radius": None,
}
TIMING = ("decision_time", "env_step_time")


class ReachCritic:
    def bind(self, metadata):
        assert metadata["suite"] == SUITE

    def q(self, state, actions):
        return 5.0 * state[2] - np.linalg.norm(np.asarray(actions)[:, :3] - [0.05, 0.0, -1.0], axis=1)


class PlungePolicy:
    def __call__(self, obs):
        return np.array([0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0])


def run(out, mode="jiti", episodes=2, resume=False, **kw):
    settings = {**{k: v for k, v in JITI_SETTINGS.items() if k in jiti_mode(mode).settings}, **kw}
    return evaluate(
        SUITE,
        [TASK],
        PlungePolicy(),
        ReachCritic(),
        out=out,
        resume=resume,
        progress=False,
        mode=mode,
        episodes=episodes,
        seed=0,
        max_steps=STEPS,
        **settings,
    )


def records(out):
    return [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]


def untimed(recs):
    return [{k: v for k, v in r.items() if k not in TIMING} for r in recs]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("eval")
    full = run(root / "full")
    run(root / "resumed", episodes=1)
    first = (root / "resumed" / "episodes.jsonl").read_text()
    resumed = run(root / "resumed", resume=True)
    base = run(root / "base", mode="base")
    return {"root": root, "full": full, "resumed": resumed, "first": first, "base": base}


def test_run_directory_and_summary_numbers(runs):
    out = runs["root"] / "full"
    recs = records(out)
    assert [r["episode"] for r in recs] == [0, 1] and all(r["task"] == f"{SUITE}/{TASK}" for r in recs)
    for r in recs:
        trace = json.loads((out / r["trace"]).read_text())
        assert trace["violated"] == r["violated"] and all(c in r["violated"] for _, c, _ in trace["events"])
        assert len(trace["decisions"]["step"]) == r["steps"] == STEPS
        assert sum(trace["decisions"]["intervened"]) == r["interventions"]
        assert sum(c != 0 for c in trace["decisions"]["chosen"]) == r["overrides"]
        assert r["decision_time"] > 0 and r["env_step_time"] > 0
    s = runs["full"]
    assert json.loads((out / "summary.json").read_text()) == json.loads(json.dumps(s))
    assert s["episodes"] == 2 and s["success_rate"] == np.mean([r["success"] for r in recs])
    assert s["esr"] == np.mean([r["elegant"] for r in recs])
    assert s["interventions_per_episode"] == np.mean([r["interventions"] for r in recs]) > 0
    assert any(r["violated"] for r in recs)  # the plunge breaks constraints: the verdict reaches the summary
    assert s["itc_violation_rate"] == {c: np.mean([c in r["violated"] for r in recs]) for c in s["itc_violation_rate"]}
    assert s["decision_overhead"] == pytest.approx(s["decision_time"] / s["env_step_time"])
    assert s["per_task"][f"{SUITE}/{TASK}"]["episodes"] == 2
    assert json.loads((out / "config.json").read_text())["jiti"]["threshold"] == 0.02
    for name in ("report.md", "success_esr.png", "q_trace.png"):
        assert (out / name).stat().st_size > 0


def test_resume_runs_only_missing_episodes_and_matches_a_fresh_run(runs):
    out = runs["root"] / "resumed"
    text = (out / "episodes.jsonl").read_text()
    assert text.startswith(runs["first"]) and len(text.splitlines()) == 2  # episode 0 was not rerun
    # same seed, same episodes: the same starts, decisions and outcomes as an uninterrupted run
    assert untimed(records(out)) == untimed(records(runs["root"] / "full"))
    fresh = json.loads((runs["root"] / "full" / "traces" / f"{SUITE}_{TASK}_1.json").read_text())["decisions"]
    again = json.loads((out / "traces" / f"{SUITE}_{TASK}_1.json").read_text())["decisions"]
    assert again["q"] == fresh["q"] and again["chosen"] == fresh["chosen"]


def test_a_run_on_two_workers_gives_the_serial_runs_episodes_traces_and_summary(runs, tmp_path):
    out = tmp_path / "parallel"
    summary = run(out, workers=2)
    serial = runs["root"] / "full"
    assert untimed(sorted(records(out), key=lambda r: r["episode"])) == untimed(records(serial))
    in_order = [json.loads(line) for line in (out / "episodes_sorted.jsonl").read_text().splitlines()]
    assert untimed(in_order) == untimed(records(serial))  # pairs line by line with the serial run
    for r in records(out):
        fresh, again = (json.loads((d / r["trace"]).read_text()) for d in (serial, out))
        fresh["decisions"].pop("time"), again["decisions"].pop("time")
        assert again == fresh
    timing = ("decision_time", "env_step_time", "decision_overhead")
    assert {k: v for k, v in summary.items() if k not in timing + ("per_task",)} == {
        k: v for k, v in runs["full"].items() if k not in timing + ("per_task",)
    }


def test_a_serial_run_resumed_on_two_workers_fills_its_gaps_as_a_fresh_run_would(runs, tmp_path):
    gappy = tmp_path / "gappy"
    shutil.copytree(runs["root"] / "full", gappy)
    kept = [line for line in (gappy / "episodes.jsonl").read_text().splitlines() if json.loads(line)["episode"] != 0]
    (gappy / "episodes.jsonl").write_text("".join(line + "\n" for line in kept))  # episode 1 done, 0 missing
    run(gappy, episodes=3, resume=True, workers=2)  # runs episodes 0 and 2 side by side
    fresh = run(tmp_path / "fresh", episodes=3)
    assert untimed(sorted(records(gappy), key=lambda r: r["episode"])) == untimed(records(tmp_path / "fresh"))
    assert json.loads((gappy / "summary.json").read_text())["esr"] == fresh["esr"]


def test_a_policy_workers_cannot_receive_is_refused_before_any_episode(tmp_path):
    with pytest.raises(UserInputError, match="cannot be sent to worker processes"):
        evaluate(
            SUITE,
            [TASK],
            lambda obs: np.zeros(7),
            None,
            out=tmp_path / "lambda",
            progress=False,
            workers=2,
            mode="base",
            episodes=2,
            max_steps=STEPS,
        )
    assert not (tmp_path / "lambda").exists()


def test_modes_start_from_the_same_init_states(runs):
    jiti, base = records(runs["root"] / "full"), records(runs["root"] / "base")
    assert [(r["init_index"], r["seed"]) for r in jiti] == [(r["init_index"], r["seed"]) for r in base]
    expected = [episode_start(0, SUITE, TASK, i, 50) for i in range(2)]
    assert [(r["init_index"], r["seed"]) for r in jiti] == expected
    assert all(r["interventions"] == 0 and r["overrides"] == 0 for r in base)
    trace = json.loads((runs["root"] / "base" / base[0]["trace"]).read_text())
    assert None not in trace["decisions"]["q"]  # base mode still logs the critic's scores


def test_episode_start_is_seeded_and_visits_distinct_inits():
    starts = [episode_start(3, SUITE, TASK, i, 50) for i in range(50)]
    assert sorted(init for init, _ in starts) == list(range(50))
    assert starts == [episode_start(3, SUITE, TASK, i, 50) for i in range(50)]
    assert starts != [episode_start(4, SUITE, TASK, i, 50) for i in range(50)]
    assert starts[:5] != [episode_start(3, SUITE, 1, i, 50) for i in range(5)]
    held_out = [episode_start(3, SUITE, TASK, i, 50, range(25, 50))[0] for i in range(25)]
    assert sorted(held_out) == list(range(25, 50))  # a subset of init states, each once, seeded
    assert held_out == [episode_start(3, SUITE, TASK, i, 50, list(range(49, 24, -1)))[0] for i in range(25)]
    with pytest.raises(UserInputError, match="expected indices in 0..49"):
        episode_start(3, SUITE, TASK, 0, 50, [10, 50])


def test_refuses_existing_run_without_resume_and_a_different_config(runs):
    out = runs["root"] / "full"
    with pytest.raises(UserInputError, match="config.json: exists; pass --resume"):
        run(out)
    with pytest.raises(UserInputError, match="field 'mode'"):
        run(out, mode="always", resume=True)


def test_resume_drops_a_partial_last_line(runs):
    out = runs["root"] / "crashed"
    shutil.copytree(runs["root"] / "full", out)
    with open(out / "episodes.jsonl", "a") as f:
        f.write('{"task": "libero_obj')
    summary = run(out, resume=True)
    assert summary["episodes"] == 2 and len(records(out)) == 2


def test_bad_arguments_are_user_errors(tmp_path):
    with pytest.raises(UserInputError, match="evaluation: field 'windw' unknown; expected one of: "):
        evaluate(SUITE, [TASK], PlungePolicy(), ReachCritic(), out=tmp_path, episodes=1, windw=3)
    with pytest.raises(UserInputError, match="episodes"):
        evaluate(SUITE, [TASK], PlungePolicy(), ReachCritic(), out=tmp_path, episodes=0)
    with pytest.raises(UserInputError, match="needs a critic"):
        evaluate(SUITE, [TASK], PlungePolicy(), None, out=tmp_path, episodes=1)
    with pytest.raises(UserInputError, match="init states"):
        evaluate(SUITE, [TASK], PlungePolicy(), None, out=tmp_path, mode="base", episodes=1, init_states=[])
    with pytest.raises(UserInputError, match=r"JITI threshold \(--threshold\) does nothing in mode 'base'"):
        evaluate(SUITE, [TASK], PlungePolicy(), None, out=tmp_path, mode="base", episodes=1, threshold=3.0)
    shapes = (
        r"JITI n_candidates \(--candidates\) .* "
        r"\(it shapes mode always, consensus, jiti, likelihood, random\): leave it out"
    )
    with pytest.raises(UserInputError, match=shapes):
        evaluate(SUITE, [TASK], PlungePolicy(), None, out=tmp_path, mode="base", episodes=1, n_candidates=8)
    assert not (tmp_path / "config.json").exists()
    with pytest.raises(
        UserInputError, match="policy act 'sample' applies to a BC policy directory; a PlungePolicy decides its own"
    ):
        evaluate(SUITE, [TASK], PlungePolicy(), None, out=tmp_path, mode="base", episodes=1, policy_act="sample")


def test_a_run_from_before_chunks_random_mode_and_init_subsets_still_resumes(runs):
    out = runs["root"] / "older"
    shutil.copytree(runs["root"] / "full", out)
    config = json.loads((out / "config.json").read_text())
    assert config["policy_act"] == "mode"
    assert config["format"] == "libero-elegant-run/2"
    assert "random_rate" not in config["jiti"]  # a jiti run records only the settings mode jiti uses
    del config["init_states"], config["jiti"]["chunk"], config["policy_act"]
    del config["format"]  # runs from before the schema had none
    assert config["device"] == "cpu"
    del config["device"]  # ... nor a device: they scored on the CPU
    config["jiti"]["random_rate"] = 0.3  # runs once recorded every JITI setting, used by their mode or not
    (out / "config.json").write_text(json.dumps(config))
    assert run(out, resume=True)["episodes"] == 2


def test_a_run_resumes_only_on_the_kind_of_device_it_scored_on(runs):
    out = runs["root"] / "on_a_gpu"
    shutil.copytree(runs["root"] / "full", out)
    config = json.loads((out / "config.json").read_text())
    (out / "config.json").write_text(json.dumps({**config, "device": "cuda (NVIDIA H100 80GB HBM3)"}))
    with pytest.raises(UserInputError, match="field 'device' is 'cuda .*' but this run has 'cpu'"):
        run(out, resume=True)


def test_a_run_resumes_only_on_the_stack_it_ran_on(runs):
    """config.json records the simulator stack and the CPU; a resume on another MuJoCo release or another
    CPU vendor is refused in one line naming both values, before any episode runs."""
    out = runs["root"] / "other_stack"
    shutil.copytree(runs["root"] / "full", out)
    config = json.loads((out / "config.json").read_text())
    assert config["stack"]["mujoco"] and config["stack"]["render"] == "none" and config["stack"]["cpu_vendor"]
    for field, value in (("mujoco", "3.14.0"), ("cpu_vendor", "SomeOtherVendor")):
        (out / "config.json").write_text(json.dumps({**config, "stack": {**config["stack"], field: value}}))
        before = (out / "episodes.jsonl").read_text()
        with pytest.raises(UserInputError, match=f"config.json was measured with {field} '{value}' but this run with"):
            run(out, resume=True, episodes=3)
        assert (out / "episodes.jsonl").read_text() == before


def test_eval_cli_hands_every_jiti_setting_to_the_evaluation(monkeypatch, tmp_path):
    """Each JITI setting has its own `elegant eval` flag and reaches `evaluate` in the typed config it builds;
    a flag left out keeps JITI's default."""
    import elegant.evaluation.runner
    from base_suites.runtime.compute import ComputeConfig
    from elegant.cli import main
    from elegant.intervention.config import JITIConfig

    calls = []
    monkeypatch.setattr(
        elegant.evaluation.runner, "evaluate", lambda *args, **kwargs: calls.append((args, kwargs)) or {}
    )
    flags = {
        "window": ("--window", "7", 7),
        "threshold": ("--threshold", "1.5", 1.5),
        "threshold_mode": ("--threshold-mode", "std", "std"),
        "n_candidates": ("--candidates", "8", 8),
        "noise_scale": ("--noise-scale", "0.2", 0.2),
        "trust_radius": ("--trust-radius", "0.4", 0.4),
        "random_rate": ("--random-rate", "0.3", 0.3),
        "min_gain": ("--min-gain", "0.05", 0.05),
        "trigger": ("--trigger", "drop", "drop"),
        "max_overrides": ("--max-overrides", "3", 3),
        "warmup": ("--warmup", "steer", "steer"),
    }
    assert set(flags) == set(JITIConfig.settings()) - {"mode"}  # mode has its own --mode
    common = ["eval", "--suite", SUITE, "--policy", "p", "--out", str(tmp_path / "run")]
    controls = {"out": str(tmp_path / "run"), "resume": False, "workers": Workers(1), "compute": ComputeConfig()}
    jiti_flags = {name: flag for name, flag in flags.items() if name != "random_rate"}  # mode jiti's settings
    assert main(common + [a for flag, text, _ in jiti_flags.values() for a in (flag, text)]) == 0
    args, kwargs = calls[-1]
    assert kwargs == controls and args[:4] == (SUITE, None, "p", None)
    assert {name: getattr(args[4].jiti, name) for name in jiti_flags} == {n: v for n, (_, _, v) in jiti_flags.items()}
    assert main(common + ["--mode", "random", "--random-rate", "0.3"]) == 0
    assert calls[-1][0][4].jiti == JITIConfig(mode="random", random_rate=0.3)
    assert main(common + ["--min-gain", "0.05"]) == 0  # a setting left out keeps the config's default
    assert calls[-1][0][4].jiti == JITIConfig(min_gain=0.05)
    assert main(common + ["--device", "cpu", "--threads", "2"]) == 0
    assert calls[-1][1]["compute"] == ComputeConfig(device="cpu", threads=2)
    assert main(common + ["--policy-act", "sample", "--init-states", "0-2,5", "--mode", "base"]) == 0
    config = calls[-1][0][4]
    assert config.policy_act == "sample" and config.init_states == (0, 1, 2, 5) and config.mode == "base"


def test_a_gate_validated_on_other_starts_runs_each_task_in_the_mode_it_chose(tmp_path):
    """`elegant gate` pairs base, JITI and `always` runs on validation starts; `evaluate(gate=...)` then runs
    a task exactly as the chosen mode's own run does (base, jiti or always), and refuses the validation starts."""
    from elegant.intervention.gate import write_gate

    run(tmp_path / "val_base", mode="base", init_states=[0, 1])
    run(tmp_path / "val_jiti", init_states=[0, 1])
    run(tmp_path / "val_always", mode="always", init_states=[0, 1])
    gate_path = tmp_path / "gate.json"
    gate = write_gate(
        tmp_path / "val_base", tmp_path / "val_jiti", gate_path, always_run=tmp_path / "val_always", budget=1.0
    )
    base_val, jiti_val = records(tmp_path / "val_base"), records(tmp_path / "val_jiti")
    row = gate["tasks"][f"{SUITE}/{TASK}"]
    assert row["episodes"] == 2 and gate["init_states"] == [0, 1]
    assert row["jiti"]["gained"] == sum(j["elegant"] and not b["elegant"] for b, j in zip(base_val, jiti_val))
    assert row["always"]["interventions"] == np.mean([r["interventions"] for r in records(tmp_path / "val_always")])
    outcome = ("init_index", "success", "elegant", "violated", "steps", "interventions")
    for mode in ("base", "jiti", "always"):
        gate["tasks"][f"{SUITE}/{TASK}"]["mode"] = mode
        gate_path.write_text(json.dumps(gate))
        run(tmp_path / f"gated_{mode}", init_states=[2, 3], gate=str(gate_path))
        run(tmp_path / f"{mode}_23", mode=mode, init_states=[2, 3])
        gated, alone = records(tmp_path / f"gated_{mode}"), records(tmp_path / f"{mode}_23")
        assert [[r[k] for k in outcome] for r in gated] == [[r[k] for k in outcome] for r in alone]
        assert json.loads((tmp_path / f"gated_{mode}" / "config.json").read_text())["gate"]["modes"] == {
            f"{SUITE}/{TASK}": mode
        }
    assert all(r["interventions"] == 0 for r in records(tmp_path / "gated_base"))
    assert (
        sum(r["interventions"] for r in records(tmp_path / "gated_always"))
        > sum(r["interventions"] for r in records(tmp_path / "gated_jiti"))
        > 0
    )
    with pytest.raises(UserInputError, match="overlaps the evaluation's starts \\(\\[1\\]\\)"):
        run(tmp_path / "overlap", init_states=[1, 2], gate=str(gate_path))
    # the same gate with other JITI settings than it validated: refused before any episode runs
    other = {**JITI_SETTINGS, "n_candidates": 5}
    with pytest.raises(UserInputError, match="gate.json: field 'agent.jiti.n_candidates' .* but this evaluation's is"):
        evaluate(
            SUITE,
            [TASK],
            PlungePolicy(),
            ReachCritic(),
            out=tmp_path / "other_settings",
            progress=False,
            episodes=2,
            seed=0,
            max_steps=STEPS,
            init_states=[2, 3],
            gate=str(gate_path),
            **other,
        )
    assert not (tmp_path / "other_settings" / "episodes.jsonl").exists()


class ForeignCritic(ReachCritic):
    def bind(self, metadata):
        raise UserInputError("critic: observation layout of env task libero_object/0 differs")


def test_a_run_refused_at_its_first_episode_leaves_nothing_and_the_fix_runs_there(tmp_path):
    out = tmp_path / "refused"
    with pytest.raises(UserInputError, match="layout of env task libero_object/0 differs"):
        evaluate(SUITE, [TASK], PlungePolicy(), ForeignCritic(), out=out, progress=False, episodes=1, max_steps=3)
    assert not out.exists()
    summary = evaluate(SUITE, [TASK], PlungePolicy(), ReachCritic(), out=out, progress=False, episodes=1, max_steps=3)
    assert summary["episodes"] == 1


def test_more_episodes_than_starts_warns_and_the_summary_counts_starts(tmp_path):
    from elegant.evaluation.runner import RepeatedStartsWarning

    with pytest.warns(RepeatedStartsWarning, match="3 episodes per task from 2 starts"):
        summary = evaluate(
            SUITE, [TASK], PlungePolicy(), out=tmp_path / "run", progress=False, mode="base", episodes=3,
            init_states=[4, 5], max_steps=2,
        )  # fmt: skip
    assert summary["starts"] == 2 and summary["episodes_per_start"] == 1.5


def test_a_base_run_that_recorded_every_jiti_setting_resumes_whatever_the_defaults_now_are(tmp_path):
    """Runs once recorded every JITI setting, used by their mode or not; a base run used none of them."""
    out = tmp_path / "base"
    run(out, mode="base", episodes=1)
    config = json.loads((out / "config.json").read_text())
    assert set(config["jiti"]) == {"chunk", "policy_adapter"}  # a base run records no JITI setting
    config["jiti"].update(window=10, threshold=1.0, threshold_mode="absolute", trigger="deviation", warmup="base",
                          n_candidates=16, noise_scale=0.1, trust_radius=None, min_gain=0.0, max_overrides=None,
                          random_rate=0.1)  # fmt: skip
    config["format"] = "libero-elegant-run/1"  # the format of the runs that recorded every setting
    (out / "config.json").write_text(json.dumps(config))
    assert run(out, mode="base", episodes=2, resume=True)["episodes"] == 2
    with pytest.raises(UserInputError, match="field 'mode' is 'base' but this run has 'always'"):
        run(out, mode="always", episodes=2, resume=True)
