"""Settings declared once: options generated from config dataclasses, recipe files, overrides, and the
migration of chain records written before the chain's config was composed of its stages' configs."""

from __future__ import annotations

import argparse
import json

import pytest

from base_suites import UserInputError
from base_suites.runtime.io import changed_fields
from base_suites.runtime.settings import add_settings_arguments, load_config, settings_from_args, with_overrides
from critics.config import TrainConfig
from elegant.chain_config import ChainConfig, check_chain_settings, load_recipe, migrate_flat_record
from elegant.evaluation.config import EvalConfig

# chain.json as the chain wrote it before its config was composed (format 1): the quickstart's settings
FLAT_QUICKSTART = {
    "suites": ["libero_object"],
    "tasks": [0],
    "demos": 100,
    "quality": "mixed",
    "critic_steps": 4000,
    "critic_gamma": 0.995,
    "critic_cql_weight": 0.2,
    "critic_reward": "elegant",
    "policy_epochs": 300,
    "episodes": 25,
    "modes": ["base", "jiti"],
    "seed": 0,
    "trust_radius": 1.5,
    "threshold": 2.0,
    "threshold_mode": "std",
    "max_steps": None,
    "chunk": 8,
    "window": 4,
    "policy_modes": None,
    "policy_successful_only": True,
    "policy_obs_noise": 0.1,
    "critic_rollouts": 50,
    "rollout_explore": 0.3,
    "critic_backup": "dataset",
    "rollout_explore_at": [8, 16],
    "critic_hidden": [64, 64],
    "critic_weight_decay": 0.1,
    "critic_mc_weight": 10.0,
    "critic_value_loss": "bce",
    "critic_explored_fraction": 0.5,
    "trigger": "drop",
    "critic_members": 1,
    "max_overrides": None,
    "warmup": "steer",
    "jiti_gate": False,
    "candidates": None,
    "policy_act": "mode",
}


def parse(config_cls, argv, **kwargs):
    parser = argparse.ArgumentParser(allow_abbrev=False)
    add_settings_arguments(parser, config_cls, **kwargs)
    return settings_from_args(parser.parse_args(argv), config_cls)


def test_options_are_generated_from_the_fields_and_only_what_was_given_is_returned():
    assert parse(TrainConfig, []) == {}
    got = parse(
        TrainConfig,
        [
            "--steps",
            "7",
            "--hidden",
            "64,32",
            "--reward",
            "elegant",
            "--lagrange",
            "--no-calibrate",
            "--bootstrap",
            "3",
        ],
        exclude=("paths",),
    )
    assert got == {
        "steps": 7,
        "hidden": [64, 32],
        "reward": "elegant",
        "with_lagrange": True,
        "calibrate": False,
        "bootstrap": 3,
    }
    with pytest.raises(SystemExit):  # argparse: one usage line and exit 2
        parse(TrainConfig, ["--reward", "bogus"], exclude=("paths",))
    with pytest.raises(SystemExit):  # a layer list is not an index range
        parse(TrainConfig, ["--hidden", "8-11"], exclude=("paths",))
    assert parse(EvalConfig, ["--init-states", "0-2,5", "--window", "4", "--mode", "base"]) == {
        "init_states": (0, 1, 2, 5),
        "jiti": {"window": 4, "mode": "base"},
    }


def test_nested_options_carry_their_stage_prefix_and_skip_what_the_chain_sets_itself():
    got = parse(
        ChainConfig,
        [
            "--critic-steps",
            "9",
            "--policy-chunk",
            "4",
            "--trust-radius",
            "0.5",
            "--tasks",
            "1-2",
            "--no-jiti-gate",
            "--suites",
            "libero_goal,libero_10",
        ],
    )
    assert got == {
        "critic": {"steps": 9},
        "policy": {"chunk": 4},
        "evaluation": {"jiti": {"trust_radius": 0.5}},
        "tasks": (1, 2),
        "jiti_gate": False,
        "suites": ("libero_goal", "libero_10"),
    }
    for derived in ("--critic-seed", "--critic-chunk", "--rollout-trust-radius", "--init-states", "--mode", "--gate"):
        with pytest.raises(SystemExit):
            parse(ChainConfig, [derived, "1"])


def test_overrides_refuse_unknown_fields_and_fields_the_owner_sets(tmp_path):
    config = with_overrides(ChainConfig(), {"critic": {"steps": 5}, "evaluation": {"jiti": {"window": 6}}})
    assert config.critic.steps == 5 and config.evaluation.jiti.window == 6 and config.policy == ChainConfig().policy
    with pytest.raises(UserInputError, match="field 'critic.stepz' unknown; expected one of: .*steps"):
        with_overrides(ChainConfig(), {"critic": {"stepz": 5}})
    with pytest.raises(UserInputError, match="field 'evaluation.jiti.mode' is set by the config that holds it"):
        with_overrides(ChainConfig(), {"evaluation": {"jiti": {"mode": "always"}}})
    recipe = tmp_path / "r.yaml"
    recipe.write_text("demos: 3\npolicy: {epochz: 2}\n")
    with pytest.raises(UserInputError, match=f"{recipe}: field 'policy.epochz' unknown"):
        load_config(ChainConfig, recipe)
    recipe.write_text("demos: [3\n")
    with pytest.raises(UserInputError, match=f"{recipe}: not valid YAML"):
        load_config(ChainConfig, recipe)
    with pytest.raises(UserInputError, match="cannot read the recipe"):
        load_recipe("no_such_recipe")


def test_the_shipped_recipes_load_and_the_effect_recipe_is_the_default():
    assert load_recipe("effect") == ChainConfig()
    for name in ("effect", "quickstart", "policy_quality"):
        load_recipe(name).validate()
    quick = load_recipe("quickstart")
    assert (quick.tasks, quick.demos, quick.critic_rollouts, quick.evaluation.episodes) == ((0,), 100, 50, 25)


def test_a_chain_refuses_a_task_or_suite_that_does_not_exist_before_it_writes(tmp_path):
    from elegant.pipeline import run_chain

    with pytest.raises(UserInputError, match="task index 50 out of range for suite .libero_10."):
        run_chain(
            str(tmp_path / "chain"),
            with_overrides(ChainConfig(), {"suites": ("libero_90", "libero_10"), "tasks": (50,)}, "chain"),
        )
    with pytest.raises(UserInputError, match="unknown suite 'libero_nope'"):
        with_overrides(ChainConfig(), {"suites": ("libero_nope",)}, "chain").validate()
    assert not list(tmp_path.iterdir())  # neither the chain directory nor its lock


def test_a_flat_chain_record_migrates_to_exactly_the_settings_that_chain_ran_with(tmp_path):
    """The quickstart's format-1 chain.json equals today's quickstart recipe, field by field, so such a
    chain directory continues; a record lacking later fields counts as running without them."""
    assert changed_fields(migrate_flat_record(FLAT_QUICKSTART), load_recipe("quickstart").record()) == []
    old = {k: v for k, v in FLAT_QUICKSTART.items() if k not in ("critic_members", "jiti_gate", "policy_act")}
    assert changed_fields(migrate_flat_record(old), load_recipe("quickstart").record()) == []
    older = migrate_flat_record({k: v for k, v in FLAT_QUICKSTART.items() if k != "policy_modes"})
    assert older["policy"]["modes"] == 5  # before the mixture size was a setting, policies had 5 components
    (tmp_path / "chain.json").write_text(json.dumps(FLAT_QUICKSTART))
    check_chain_settings(str(tmp_path), load_recipe("quickstart"))  # accepted, and rewritten in format 2
    assert json.loads((tmp_path / "chain.json").read_text())["format"] == "libero-elegant-chain/3"
    with pytest.raises(UserInputError, match=r"other settings \(critic.steps\)"):
        check_chain_settings(str(tmp_path), with_overrides(load_recipe("quickstart"), {"critic": {"steps": 1}}))
    with pytest.raises(UserInputError, match="field 'chunky' is not a setting of any chain format"):
        migrate_flat_record({**FLAT_QUICKSTART, "chunky": 1})


def test_a_format_2_chain_from_before_later_settings_and_default_changes_still_resumes(tmp_path):
    """A chain record keeps the stage fields the chain sets itself at their defaults of the day (the critic's
    chunk was 1) and lacks settings added since (the rollouts' obs): neither makes it another chain."""
    settings = load_recipe("quickstart").record()
    settings["critic"]["chunk"] = 1
    del settings["rollout"]["obs"]
    (tmp_path / "chain.json").write_text(json.dumps({"format": "libero-elegant-chain/2", "settings": settings}))
    check_chain_settings(str(tmp_path), load_recipe("quickstart"))
    with pytest.raises(UserInputError, match=r"holds a chain with other settings \(rollout.obs\)"):
        check_chain_settings(str(tmp_path), with_overrides(load_recipe("quickstart"), {"rollout": {"obs": "vla"}}))
