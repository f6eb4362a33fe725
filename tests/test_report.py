"""Reports from synthetic run directories: report.md and non-empty PNGs, side-by-side comparison, robustness."""

import json

import pytest

from base_suites import UserInputError
from elegant.evaluation.metrics import summarize
from elegant.reporting.report import atomic_write, compare_runs, perturbation_axis, write_run_report

PNG = b"\x89PNG\r\n\x1a\n"


def make_run(path, mode, successes, perturbation=None, with_q=True, **config_fields):
    """A run directory as `evaluate` leaves it: config (plus `config_fields`), records with traces, summary."""
    (path / "traces").mkdir(parents=True)
    records = []
    for i, ok in enumerate(successes):
        steps = 30
        intervened = [t in (12, 20 + i) for t in range(steps)]
        trace = {
            "task": f"libero_goal/{i % 2}",
            "episode": i,
            "init_index": i,
            "mode": mode,
            "success": ok,
            "elegant": ok and i % 2 == 0,
            "violated": [] if ok else ["collision"],
            "jiti": {},
            "segments": {"collision": [ok, True]},
            "decisions": {
                "step": list(range(steps)),
                "q": [1.0 + 0.01 * t if with_q else None for t in range(steps)],
                "mean": [None] * 10 + [1.0 + 0.01 * t for t in range(10, steps)],
                "tau": [None] * 10 + [0.05] * (steps - 10),
                "chosen_q": [1.2 + 0.01 * t if with_q else None for t in range(steps)],
                "intervened": intervened,
            },
        }
        name = f"traces/libero_goal_{i % 2}_{i}.json"
        (path / name).write_text(json.dumps(trace))
        records.append(
            {
                "task": trace["task"],
                "episode": i,
                "init_index": i,
                "seed": 100 + i,
                "success": ok,
                "elegant": trace["elegant"],
                "violated": trace["violated"],
                "interventions": sum(intervened),
                "overrides": 1,
                "steps": steps,
                "decision_time": 1e-4,
                "env_step_time": 1e-2,
                "trace": name,
            }
        )
    config = {
        "suite": "libero_goal",
        "tasks": [0, 1],
        "policy": "/p",
        "critic": "/c",
        "mode": mode,
        "episodes": len(successes),
        "seed": 0,
        "perturbation": perturbation,
        "max_steps": None,
        "obs": "lowdim",
        "jiti": {
            "window": 10,
            "threshold": 1.0,
            "threshold_mode": "absolute",
            "n_candidates": 16,
            "policy_adapter": "BCPolicy",
        },
        **config_fields,
    }
    summary = {"config": config, **summarize(records)}
    (path / "summary.json").write_text(json.dumps(summary))
    (path / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    return summary, records


def assert_png(path):
    data = path.read_bytes()
    assert data.startswith(PNG) and len(data) > 2000


def test_run_report_writes_markdown_and_plots(tmp_path):
    summary, records = make_run(tmp_path / "run", "jiti", [True, False, True, True])
    files = write_run_report(tmp_path / "run", summary, records)
    assert {f.name for f in files} == {"report.md", "report.html", "success_esr.png", "q_trace.png"}
    assert_png(tmp_path / "run" / "success_esr.png")
    assert_png(tmp_path / "run" / "q_trace.png")
    md = (tmp_path / "run" / "report.md").read_text()
    assert (
        "| success rate [95% interval] | 75.0% [30.1%, 95.4%] |" in md
        and "| ESR (elegant success rate) [95% interval] | 50.0% [15.0%, 85.0%] |" in md
    )
    assert "| succeeded, but violated: collision | 0.0% |" in md
    assert "| libero_goal/1 | 2 | 50.0% | 0.0% |" in md and "## Q trace: libero_goal/0, episode 0" in md
    assert "- policy: `/p` (policy act: mode)" in md  # a run from before the act was recorded
    summary, records = make_run(tmp_path / "sampled", "jiti", [True], policy_act="sample")
    write_run_report(tmp_path / "sampled", summary, records)
    assert "- policy: `/p` (policy act: sample)" in (tmp_path / "sampled" / "report.md").read_text()


def test_run_report_without_critic_has_no_q_trace(tmp_path):
    summary, records = make_run(tmp_path / "run", "base", [True, False], with_q=False)
    files = write_run_report(tmp_path / "run", summary, records)
    assert [f.name for f in files] == ["report.md", "report.html", "success_esr.png"]
    assert (
        not (tmp_path / "run" / "q_trace.png").exists()
        and "Q trace" not in (tmp_path / "run" / "report.md").read_text()
    )


def test_compare_runs_side_by_side_with_robustness(tmp_path):
    make_run(tmp_path / "ori", "jiti", [True, True, True, False])
    make_run(tmp_path / "init", "jiti", [True, False, False, False], perturbation="init:3")
    make_run(tmp_path / "base", "base", [True, False, True, False])
    result = compare_runs([tmp_path / "ori", tmp_path / "init", tmp_path / "base"], out=tmp_path / "cmp")
    assert [r["label"] for r in result["runs"]] == ["ori (jiti)", "init (jiti)", "base (base)"]
    assert (
        "| success rate [95% interval] | 75.0% [30.1%, 95.4%] | 25.0% [4.6%, 69.9%] | 50.0% [15.0%, 85.0%] |"
        in result["markdown"]
    )
    (group,) = result["robustness"].values()  # the base run has no unperturbed partner of its own mode
    assert group["success"]["gap"] == {"init": 0.5} and group["success"]["pro"] == 0.25
    assert group["elegant"]["acc_ori"] == 0.5 and group["elegant"]["acc"] == {"init": 0.25}
    assert_png(tmp_path / "cmp" / "comparison.png")
    assert (tmp_path / "cmp" / "comparison.md").read_text().startswith(result["markdown"])
    make_run(tmp_path / "init_sampled", "jiti", [False] * 4, perturbation="init:3", policy_act="sample")
    again = compare_runs([tmp_path / "ori", tmp_path / "init", tmp_path / "init_sampled"])
    (group,) = again["robustness"].values()  # the sampling policy's perturbed run has no unperturbed partner
    assert group["success"]["acc"] == {"init": 0.25}
    make_run(tmp_path / "init_again", "jiti", [True] * 4, perturbation="init:5")  # the same cell as "init"
    with pytest.raises(UserInputError, match=r"runs .*init and .*init_again are both the 'init' cell"):
        compare_runs([tmp_path / "ori", tmp_path / "init", tmp_path / "init_again"])


def test_compare_runs_pairs_later_runs_with_the_first_on_shared_starts(tmp_path):
    make_run(tmp_path / "base", "base", [True, False, False, False])
    make_run(tmp_path / "jiti", "jiti", [True, True, True, False])
    result = compare_runs([tmp_path / "base", tmp_path / "jiti"])
    (paired,) = result["paired"]
    assert paired["run"] == "jiti (jiti)" and paired["success"]["pairs"] == 4
    assert (paired["success"]["only_after"], paired["success"]["only_before"]) == (2, 0) and paired["success"][
        "p_value"
    ] == 0.5
    assert paired["elegant"]["difference"] == 0.25  # episode 2 (even index) turns elegant
    assert (
        "| jiti (jiti) | 4 | +50.0 points (2 gained, 0 lost; 2 of 4 starts better, 0 worse, p = 0.5) "
        "| +25.0 points (1 gained, 0 lost; 1 of 4 starts better, 0 worse, p = 1) |" in result["markdown"]
    )


def test_compare_runs_recomputes_metrics_from_the_episodes(tmp_path):
    summary, _ = make_run(tmp_path / "old", "base", [True, False])
    for key in ("success_ci95", "esr_ci95", "success_with_violation"):  # a run written before these existed
        del summary[key]
    (tmp_path / "old" / "summary.json").write_text(json.dumps(summary))
    assert "| success rate [95% interval] | 50.0% [9.5%, 90.5%] |" in compare_runs([tmp_path / "old"])["markdown"]
    (tmp_path / "old" / "episodes.jsonl").write_text("")
    with pytest.raises(UserInputError, match="episodes.jsonl: no finished episodes"):
        compare_runs([tmp_path / "old"])


def test_compare_runs_counts_only_the_episodes_the_run_asks_for(tmp_path):
    summary, _ = make_run(tmp_path / "run", "base", [True, True, False, False])
    summary["config"]["episodes"] = 2  # resumed with fewer episodes: the log keeps episodes 2 and 3
    (tmp_path / "run" / "summary.json").write_text(json.dumps(summary))
    assert "| success rate [95% interval] | 100.0% [34.2%, 100.0%] |" in compare_runs([tmp_path / "run"])["markdown"]


def test_compare_runs_without_out_writes_nothing_and_refuses_non_runs(tmp_path):
    make_run(tmp_path / "a", "jiti", [True])
    result = compare_runs([tmp_path / "a"])
    assert result["files"] == [] and result["robustness"] == {}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a"]
    with pytest.raises(UserInputError, match="no summary.json"):
        compare_runs([tmp_path / "missing"])


def test_perturbation_axis_and_atomic_write(tmp_path):
    assert perturbation_axis(None) == "ori" and perturbation_axis("init:3,language") == "init+language"
    assert perturbation_axis("init:2@nudge") == "init@nudge"  # fresh starts, not LIBERO-PRO's init axis
    # LIBERO-PRO's semantic and task axes, and a shipped against a generated variant, are columns of their own
    assert perturbation_axis("language@shipped") == "language@shipped"
    assert perturbation_axis("language@target_swap") == "language@target_swap"
    assert perturbation_axis("object@shipped") != perturbation_axis("object")
    atomic_write(tmp_path / "f.txt", "one")
    atomic_write(tmp_path / "f.txt", b"two")
    assert (tmp_path / "f.txt").read_text() == "two" and [p.name for p in tmp_path.iterdir()] == ["f.txt"]


def test_plots_show_intervals_and_legend_only_what_they_draw(monkeypatch, tmp_path):
    from elegant.reporting import report

    drawn = []
    monkeypatch.setattr(report, "save_figure", lambda fig, path: drawn.append(fig) or path)
    decisions = {
        "step": [0, 8, 16],
        "q": [-1.0, -2.0, -1.5],
        "mean": [None, -1.5, -1.5],
        "tau": [None, 0.5, 0.5],
        "chosen_q": [-1.0, -2.0, -1.5],
        "intervened": [False, False, False],
    }
    trace = {"task": "s/0", "episode": 0, "mode": "base", "success": True, "elegant": False, "violated": ["collision"],
             "segments": {"collision": [True, False], "alignment": [False, True]}, "decisions": decisions}  # fmt: skip
    report.plot_q_trace(trace, tmp_path / "q.png")
    legend = [t.get_text() for t in drawn[-1].axes[0].get_legend().get_texts()]
    assert legend == ["collision violated", "alignment violated", "Q(s, base action)"]  # no band, no intervention
    assert "critic's estimate" in drawn[-1].axes[0].get_ylabel()
    report.plot_bars(["s/0"], {"success": [0.5]}, "t", tmp_path / "b.png", {"success": [(0.3, 0.8)]})
    errorbars = next(c for c in drawn[-1].axes[0].containers if type(c).__name__ == "ErrorbarContainer")
    (segment,) = errorbars.lines[2][0].get_segments()
    low, high = segment[:, 1]
    assert (low, high) == pytest.approx((0.3, 0.8))  # the error bar spans the interval


def test_a_run_header_names_the_settings_its_mode_used_and_only_those():
    from elegant.reporting.report import _settings_line

    jiti = {"window": 4, "threshold": 2.0, "threshold_mode": "std", "trigger": "drop", "warmup": "steer",
            "n_candidates": 16, "trust_radius": 1.5, "min_gain": 0.0, "max_overrides": None, "random_rate": 0.1,
            "chunk": 8, "policy_adapter": "BCPolicy"}  # fmt: skip
    config = {"jiti": jiti, "candidate_source": "the policy's samples"}
    assert _settings_line({**config, "mode": "base"}) == "JITI: not used (the base policy acts alone)"
    always = _settings_line({**config, "mode": "always"})
    assert "trust radius 1.5" in always and "the policy's samples" in always and "trigger" not in always
    full = _settings_line({**config, "mode": "jiti"})
    assert all(s in full for s in ("trigger drop", "warm-up steer", "window 4", "threshold 2.0 (std)", "every 8 steps"))
    assert "0.1 of decisions" in _settings_line({**config, "mode": "random"})
