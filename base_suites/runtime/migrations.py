"""The one migration table: for each kind of record the project writes and reads back (to resume a run or
check what it ran with), the settings added after some such records were written, with the value that
reproduces what those records' runs did. A record without the setting counts as holding that value
(`changed_fields(..., added=added_later(kind))`); a dict value names settings added inside a nested
record, a function computes the value from the old record. `SAME_AS_NOW` stands for "whatever this run
has": a setting that did nothing before it existed. Add a setting to a record kind here, once, when the
setting is introduced.
"""

from __future__ import annotations

import copy
from typing import Any

SAME_AS_NOW = "<same as this run>"


def _render_quality_of(record: dict) -> str | None:
    """Before the render quality was a setting, every image observation was rendered without shadows,
    reflections or multisampling ("fast"); a run without images records None."""
    return None if record.get("obs", "lowdim") == "lowdim" else "fast"


_ADDED_LATER: dict[str, dict[str, Any]] = {
    # elegant eval's RUN/config.json: before chunking (one action per decision), before mode "random" (so its
    # rate had no effect), before a subset of init states, the minimum gain, the one-sided trigger, the
    # override budget, the steered warm-up, the policy act, the render quality and the VLA image size
    "eval run": {
        "render_quality": _render_quality_of,
        "vla_image_size": None,
        "format": "libero-elegant-run/1",
        "init_states": None,
        "policy_act": "mode",
        "candidate_source": SAME_AS_NOW,
        "device": "cpu",
        "jiti": {
            "chunk": 1,
            "random_rate": SAME_AS_NOW,
            "min_gain": 0.0,
            "trigger": "deviation",
            "max_overrides": None,
            "warmup": "base",
        },
    },
    # elegant lifelong's OUT/config.json: before the mixture size was a setting, policies had 5 components;
    # before the batch size was one, stages trained in batches of 256; before ER, EWC, PackNet and multitask,
    # SeqL had no settings of its own; before pre-training, every run started from a fresh network; before
    # the goal-relative encoding, stage policies read the task one-hot
    "lifelong run": {
        "format": "libero-elegant-lifelong/1",
        "modes": 5,
        "batch_size": 256,
        "algorithm_settings": {},
        "pretrained": None,
        "encoding": "task-onehot",
    },
    # train-policy's checkpoint fingerprint: before the success filter, observation noise, the lifelong
    # baselines' mechanisms and pre-training, and the goal-relative encoding
    "policy checkpoint": {
        "successful_only": False,
        "config": {"obs_noise": 0.0, "encoding": "task-onehot"},
        "continual": None,
        "pretrained": None,
    },
    # train-critic's checkpoint config (encoding and tasks: before the goal-relative encoding)
    "critic checkpoint": {
        "chunk": 1,
        "backup": "policy",
        "weight_decay": 0.0,
        "mc_weight": 0.0,
        "value_loss": "mse",
        "explored_fraction": 0.0,
        "bootstrap": None,
        "encoding": "task-onehot",
        "tasks": None,
    },
    # the agent a gate file (or a run it reads) records: before the policy act
    "gate agent": {"policy_act": "mode"},
    # chain.json's settings in format 2: before the rollouts' observation mode and the encodings
    "chain": {
        "rollout": {"obs": "lowdim"},
        "policy": {"encoding": "task-onehot"},
        "critic": {"encoding": "task-onehot", "tasks": None},
    },
    # chain.json in its flat format 1 (`elegant.chain_config.migrate_flat_record` maps it to format 2); None
    # there stands for the stage's default of the day
    "flat chain": {
        "chunk": 1,
        "window": None,
        "policy_successful_only": False,
        "policy_obs_noise": 0.0,
        "critic_rollouts": 0,
        "rollout_explore": 0.3,
        "critic_backup": "policy",
        "rollout_explore_at": None,
        "critic_hidden": [256, 256],
        "critic_weight_decay": 0.0,
        "critic_mc_weight": 0.0,
        "critic_value_loss": "mse",
        "critic_explored_fraction": 0.0,
        "trigger": None,
        "critic_members": 1,
        "max_overrides": None,
        "warmup": None,
        "jiti_gate": False,
        "candidates": None,
        "policy_act": "mode",
        "policy_modes": 5,
    },
}


def added_later(kind: str) -> dict[str, Any]:
    """The settings added to records of `kind` after some were written (a copy: callers may fill it in)."""
    return copy.deepcopy(_ADDED_LATER[kind])
