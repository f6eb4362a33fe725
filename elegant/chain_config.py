"""The chain's settings: one config composed of its stages' configs (docs/design.md, configuration).

`ChainConfig` holds what the chain itself decides (suites, tasks, data sizes, which modes, the seed) and
one config per stage: the policy's `BCConfig`, the rollouts' `RolloutConfig`, the critic's `TrainConfig`
and the evaluation's `EvalConfig` (with its `JITIConfig`). Settings one stage must share with another are
set by the chain (`derived`): every stage's seed is the chain's, the critic's chunk is the policy's, the
rollouts' trust radius and horizon are the evaluation's, and the chain splits the init states between
rollouts and evaluation. Its defaults are the recommended recipe (the effect benchmark's); named recipes
are YAML files under `configs/` (`load_recipe`).

chain.json records the settings as `{"format": CHAIN_RECORD.tag, "settings": ...}`; older formats are
upgraded one step at a time (`CHAIN_RECORD`). Chains written before the composition (format 1: one flat
record of 37 fields) are read through `migrate_flat_record`, the table that says where each old field lives
now and what an old chain that lacked it ran with.
"""

from __future__ import annotations

import copy
import json
import os
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

from base_suites import task_specs
from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import atomic_write, changed_fields, read_json_file
from base_suites.runtime.records import RecordFormat, fill_missing
from base_suites.runtime.settings import check_derived, index_list, load_config, nested, setting, with_overrides
from critics.config import TrainConfig
from elegant.evaluation.config import EvalConfig, RolloutConfig
from elegant.intervention.modes import jiti_mode, mode_names
from elegant.policies.bc_config import BCConfig

RECIPES = Path(__file__).resolve().parent.parent / "configs"
_BRANCH_POINTS = tuple(range(8, 129, 8))


@dataclass(frozen=True)
class ChainConfig:
    """Which tasks, how much data and training, which modes to compare, and each stage's settings."""

    suites: tuple[str, ...] = setting(
        ("libero_object", "libero_goal"), "suites, each with its own demos, rollouts and runs"
    )
    tasks: tuple[int, ...] | None = setting(None, "task indices for every suite (default: all)", parse=index_list)
    seed: int = setting(0, "every stage's seed (demos, policy, rollouts, critic, evaluation)")
    demos: int = setting(50, "scripted demos per task")
    quality: str = setting("mixed", "the demos' execution quality (elegant demos --quality)")
    successful_only: bool = setting(True, "the policy clones only the demos that succeeded")
    policy: BCConfig = nested(BCConfig, "policy-", derived=("seed",))
    critic_rollouts: int = setting(
        100,
        "rollouts per task of the trained policy added to the critic's data (0: demos only); they start "
        "from the first half of the init states and every mode is evaluated from the second half",
    )
    rollout: RolloutConfig = nested(
        lambda: RolloutConfig(explore_at=_BRANCH_POINTS),
        "rollout-",
        derived=("episodes", "seed", "trust_radius", "init_states", "max_steps", "policy_act"),
    )
    critic: TrainConfig = nested(
        lambda: TrainConfig(explored_fraction=0.5),
        "critic-",
        derived=("paths", "seed", "chunk", "bootstrap", "tasks"),
    )
    critic_members: int = setting(
        3, "critics trained on bootstrap resamples of the data; JITI overrides only when all prefer it"
    )
    modes: tuple[str, ...] = setting(("base", "always", "jiti"), "the modes evaluated, e.g. base,jiti")
    evaluation: EvalConfig = nested(
        lambda: EvalConfig(episodes=50),
        "",
        derived=("seed", "init_states", "gate", "jiti.mode"),
    )
    jiti_gate: bool = setting(
        True,
        "validate base, JITI and always on the rollouts' starts first, and run each task in the mode that helped "
        "most there (always only within 40% of its interventions)",
    )

    def validate(self) -> None:
        """Refuse, before hours of demos, any setting a stage would refuse later, and settings that
        contradict each other."""
        unknown = [m for m in self.modes if m not in mode_names()]
        if unknown or not self.modes:
            raise UserInputError(f"chain modes {list(self.modes)}: expected some of {', '.join(mode_names())}")
        if not self.suites:
            raise UserInputError("chain suites: give at least one suite")
        for suite in self.suites:  # an unknown suite or task is refused before the chain directory exists
            task_specs(suite, self.tasks)
        for name in ("demos", "critic_members"):
            if getattr(self, name) < 1:
                raise UserInputError(f"chain {name} must be >= 1, got {getattr(self, name)}")
        if self.critic_rollouts < 0:
            raise UserInputError(f"chain critic_rollouts must be >= 0, got {self.critic_rollouts}")
        check_derived(self, "chain")
        for stage, check in (("policy", self.policy.validate), ("critic", self.critic.validate)):
            try:
                check()
            except UserInputError as e:
                raise UserInputError(f"chain {stage} settings: {e}") from None
        if self.critic.explored_fraction > 0 and not self.critic_rollouts:
            raise UserInputError("chain critic.explored_fraction needs explored decisions: give critic_rollouts > 0")
        if self.validated_modes() and not self.critic_rollouts:
            raise UserInputError(
                "chain jiti_gate validates on the rollouts' starts, apart from the evaluated ones: give "
                "critic_rollouts > 0"
            )

    def needs_critic(self) -> bool:
        """Whether any evaluated mode needs a critic (base alone, the policy benchmark, only logs its scores)."""
        return any(jiti_mode(m).needs_critic for m in self.modes)

    def validated_modes(self) -> tuple[str, ...]:
        """The modes a gated chain validates on the rollouts' starts: base, jiti and, when evaluated, always
        (none without the gate)."""
        if not (self.jiti_gate and "jiti" in self.modes):
            return ()
        return ("base", "jiti", *(("always",) if "always" in self.modes else ()))

    def policy_config(self) -> BCConfig:
        return replace(self.policy, seed=self.seed)

    def critic_config(self, member: int) -> TrainConfig:
        """Critic `member` (0-based): with several members, member k trains on bootstrap resample seed + k."""
        if self.critic_members == 1:
            return replace(self.critic, seed=self.seed, chunk=self.policy.chunk)
        return replace(self.critic, seed=self.seed + member, bootstrap=self.seed + member, chunk=self.policy.chunk)

    def rollout_config(self, init_states: list[int] | None) -> RolloutConfig:
        return replace(
            self.rollout,
            episodes=self.critic_rollouts,
            seed=self.seed,
            trust_radius=self.evaluation.jiti.trust_radius,
            max_steps=self.evaluation.max_steps,
            init_states=None if init_states is None else tuple(init_states),
        )

    def eval_config(self, mode: str, init_states: list[int] | None, gate: str | None = None) -> EvalConfig:
        """How the chain evaluates `mode` from `init_states` (None: all), with `gate` in mode jiti; a run
        records only the JITI settings its mode uses (a base run none)."""
        jiti = replace(self.evaluation.jiti, mode=mode)
        starts = None if init_states is None else tuple(init_states)
        return replace(self.evaluation, seed=self.seed, init_states=starts, gate=gate, jiti=jiti)

    def record(self) -> dict[str, Any]:
        """The settings as chain.json stores them (JSON types)."""
        return json.loads(json.dumps(asdict(self)))


def load_recipe(path: str | os.PathLike) -> ChainConfig:
    """A chain recipe (YAML nested like `ChainConfig`; what it leaves out keeps the defaults). A name
    without a directory, e.g. "quickstart", is a recipe under configs/."""
    path = Path(path)
    if path.suffix == "" and path.parent == Path("."):
        path = RECIPES / f"{path}.yaml"
    return load_config(ChainConfig, path)


# Format 1 chain.json: one flat record. Where each of its fields lives in `ChainConfig` now, and, for the
# fields a format-1 record may lack (added later) or hold None for ("the stage's default" then), the value
# such a chain ran with.
_FLAT_FIELDS = {
    "suites": "suites",
    "tasks": "tasks",
    "seed": "seed",
    "demos": "demos",
    "quality": "quality",
    "modes": "modes",
    "critic_rollouts": "critic_rollouts",
    "critic_members": "critic_members",
    "jiti_gate": "jiti_gate",
    "policy_successful_only": "successful_only",
    "policy_epochs": "policy.epochs",
    "chunk": "policy.chunk",
    "policy_modes": "policy.modes",
    "policy_obs_noise": "policy.obs_noise",
    "critic_steps": "critic.steps",
    "critic_gamma": "critic.gamma",
    "critic_cql_weight": "critic.cql_weight",
    "critic_reward": "critic.reward",
    "critic_backup": "critic.backup",
    "critic_hidden": "critic.hidden",
    "critic_weight_decay": "critic.weight_decay",
    "critic_mc_weight": "critic.mc_weight",
    "critic_value_loss": "critic.value_loss",
    "critic_explored_fraction": "critic.explored_fraction",
    "rollout_explore": "rollout.explore",
    "rollout_explore_at": "rollout.explore_at",
    "episodes": "evaluation.episodes",
    "max_steps": "evaluation.max_steps",
    "policy_act": "evaluation.policy_act",
    "trust_radius": "evaluation.jiti.trust_radius",
    "threshold": "evaluation.jiti.threshold",
    "threshold_mode": "evaluation.jiti.threshold_mode",
    "window": "evaluation.jiti.window",
    "trigger": "evaluation.jiti.trigger",
    "max_overrides": "evaluation.jiti.max_overrides",
    "warmup": "evaluation.jiti.warmup",
    "candidates": "evaluation.jiti.n_candidates",
}
# the fields a format-1 record may lack, each with the value such a chain ran with (None: the stage's default
# of the day, as `_FLAT_NONE_MEANS` says)
_FLAT_ADDED = {
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
}
_FLAT_NONE_MEANS = {
    "window": 10,
    "trigger": "deviation",
    "warmup": "base",
    "candidates": 16,
    "policy_modes": 16,
    "threshold": 1.0,
    "threshold_mode": "absolute",
}


def migrate_flat_record(record: dict[str, Any]) -> dict[str, Any]:
    """A format-1 (flat) chain record as today's nested settings, equal to what that chain ran with."""
    flat = {**_FLAT_ADDED, **record}
    if flat["rollout_explore_at"] is not None:  # a rate was recorded but never used beside branch points
        flat["rollout_explore"] = 0.0
    nested_record: dict[str, Any] = {}
    for name, value in flat.items():
        if name not in _FLAT_FIELDS:
            raise UserInputError(f"chain.json: field {name!r} is not a setting of any chain format")
        if value is None and name in _FLAT_NONE_MEANS:
            value = _FLAT_NONE_MEANS[name]
        *parents, leaf = _FLAT_FIELDS[name].split(".")
        node = nested_record
        for parent in parents:
            node = node.setdefault(parent, {})
        node[leaf] = value
    # a format-1 chain's stages ran with the stage defaults of their day where it set nothing; for every
    # setting such a record can lack, those are today's stage defaults (the settings whose defaults became
    # the recipe since are all in its record), not the chain's
    base = ChainConfig(policy=BCConfig(), rollout=RolloutConfig(), critic=TrainConfig(), evaluation=EvalConfig())
    return with_overrides(base, nested_record, "chain.json").record()


def _chain_from_v1(record: dict[str, Any]) -> dict[str, Any]:
    """A format-1 chain.json (one flat record, no format field) as format 2: the settings nested."""
    return {"settings": migrate_flat_record(record)}


def _chain_from_v2(record: dict[str, Any]) -> dict[str, Any]:
    """A format-2 chain.json as format 3: before the rollouts' observation mode and the encodings, chains
    recorded low-dimensional rollouts and task one-hot models over every task of the files."""
    settings = {
        "rollout": {"obs": "lowdim"},
        "policy": {"encoding": "task-onehot"},
        "critic": {"encoding": "task-onehot", "tasks": None},
    }
    if isinstance(record.get("settings"), dict):
        record["settings"] = fill_missing(record["settings"], settings)
    return record


CHAIN_RECORD = RecordFormat("libero-elegant-chain", 3, {1: _chain_from_v1, 2: _chain_from_v2})


def _chosen(record: dict[str, Any]) -> dict[str, Any]:
    """A chain record without the stage fields the chain sets itself (`nested(..., derived=...)`): they
    follow from the chain's own settings, and their recorded defaults say nothing of what it ran."""
    record = copy.deepcopy(record)
    for f in fields(ChainConfig):
        for path in f.metadata.get("derived", ()):
            *parents, leaf = path.split(".")
            node = record.get(f.name)
            for parent in parents:
                node = node.get(parent) if isinstance(node, dict) else None
            if isinstance(node, dict):
                node.pop(leaf, None)
    return record


def check_chain_settings(out: str, config: ChainConfig) -> None:
    """Record `config` in OUT/chain.json, or refuse, in one line naming the fields, a chain directory that
    holds a chain with other settings (any format)."""
    path = os.path.join(out, "chain.json")
    settings = config.record()
    if os.path.exists(path):
        stored = CHAIN_RECORD.upgrade(read_json_file(path, "chain settings"), path)["settings"]
        changed = changed_fields(_chosen(stored), _chosen(settings))
        if changed:
            raise UserInputError(
                f"{path}: {out} holds a chain with other settings ({', '.join(k for k, _, _ in changed)}); choose "
                "another --out"
            )
    atomic_write(path, json.dumps({"format": CHAIN_RECORD.tag, "settings": settings}, indent=2))
