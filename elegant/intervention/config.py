"""JITI's settings: one frozen dataclass, each setting declared once with its reason (docs/design.md, JITI).

The evaluation runner, the CLI and the chain take their JITI settings from these fields. The defaults are
the recommended recipe (docs/design.md, JITI; configs/effect.yaml). Run configs record `JITIConfig.record()`:
the mode and the settings its decisions depend on (its `JITIMode.settings`), no others. A mode is one registered
object (`elegant.intervention.modes`): its trigger (when to draw and re-rank candidates), its selector
(which candidate runs), whether it needs a critic, and the settings it uses.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import asdict, dataclass, fields
from typing import Any, Literal

from base_suites.runtime.errors import UserInputError
from base_suites.runtime.settings import check_choices, setting
from elegant.intervention.modes import jiti_mode, mode_names
from elegant.policies.protocol import DEFAULT_NOISE_SCALE

ThresholdMode = Literal["absolute", "std"]
TriggerName = Literal["deviation", "drop", "none"]
Warmup = Literal["base", "steer"]

MAX_CANDIDATES = 4096  # far beyond any useful count; a typo of more would exhaust memory at the first decision


def candidates_setting() -> Any:
    """N, declared once for JITI's choices and the recorded rollouts' explored decisions (`RolloutConfig`)."""
    return setting(
        16, "candidates drawn from the policy per re-ranked decision, the base plan one of them", flag="--candidates"
    )


def trust_radius_setting() -> Any:
    """The trust radius, declared once: JITI chooses within it and `elegant rollouts` explores within it
    (`RolloutConfig`), so a critic learns from the alternatives it will be asked to judge."""
    return setting(
        1.5,
        "only candidates within this distance of the base plan may be chosen, or explored in recorded rollouts "
        "(None: no limit)",
    )


@dataclass(frozen=True)
class JITIConfig:
    """How JITI decides. `mode` names a registered mode (`elegant.intervention.modes`): "jiti" (re-rank at
    critical moments), "always" (at every decision: the V-GPS baseline), "base" (never; the critic's
    scores are still logged), "random" (a random eligible candidate at a `random_rate` of decisions, or
    at `random_steps`: the control, and the exploration of recorded rollouts), and the critic-free
    controls "likelihood" and "consensus"."""

    mode: str = setting(
        "jiti",
        "; ".join(f"{name}: {jiti_mode(name).help}" for name in mode_names()),
        choices=mode_names,
    )
    window: int = setting(4, "JITI's window: the number of past decisions whose scores set the reference m_t")
    threshold: float = setting(2.0, "tau: how far q_t may stray from m_t before JITI intervenes")
    threshold_mode: ThresholdMode = setting("std", "tau in Q units (absolute) or in the window's std (std)")
    trigger: TriggerName = setting(
        "drop", "mode jiti's critical moment: |q - m| > tau (deviation), m - q > tau (drop) or none"
    )
    warmup: Warmup = setting(
        "steer",
        "what mode jiti's first --window decisions execute: the base plan (base) or the critic's choice (steer)",
    )
    n_candidates: int = candidates_setting()
    noise_scale: float = setting(
        DEFAULT_NOISE_SCALE, "std of the Gaussian candidates around a policy's action when it cannot sample its own"
    )
    trust_radius: float | None = trust_radius_setting()
    min_gain: float = setting(0.0, "a candidate must beat the base plan's score by more than this to replace it")
    max_overrides: int | None = setting(None, "mode jiti stops overriding after this many per episode (default: none)")
    random_rate: float = setting(0.1, "mode random: the fraction of decisions given a random eligible candidate")

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Refuse any setting that is unknown, out of range or not a number, with one line naming it."""
        check_choices(self, "JITI")
        mode = jiti_mode(self.mode)
        if mode.check is not None:
            mode.check(self)
        if not int(self.window) >= 1:
            raise UserInputError(f"JITI window must be >= 1, got {self.window}")
        if not 2 <= int(self.n_candidates) <= MAX_CANDIDATES:
            raise UserInputError(
                f"JITI n_candidates must lie in 2..{MAX_CANDIDATES} (the base action plus alternatives, each "
                f"scored by the critic at every re-ranked decision), got {self.n_candidates}"
            )
        if not (float(self.threshold) >= 0 and float(self.noise_scale) >= 0):
            raise UserInputError(
                f"JITI threshold and noise_scale must be >= 0, got {self.threshold} and {self.noise_scale}"
            )
        if self.trust_radius is not None and not float(self.trust_radius) > 0:
            raise UserInputError(f"JITI trust_radius must be > 0 (or None for no limit), got {self.trust_radius}")
        if not float(self.min_gain) >= 0:
            raise UserInputError(f"JITI min_gain must be >= 0, got {self.min_gain}")
        if not 0.0 <= float(self.random_rate) <= 1.0:
            raise UserInputError(f"JITI random_rate must lie in [0, 1], got {self.random_rate}")
        if self.max_overrides is not None and int(self.max_overrides) < 0:
            raise UserInputError(f"JITI max_overrides must be >= 0 (or None for no limit), got {self.max_overrides}")

    @classmethod
    def settings(cls) -> tuple[str, ...]:
        """The names of the settings, in declaration order (mode first)."""
        return tuple(f.name for f in fields(cls))

    def record(self) -> dict[str, Any]:
        """The mode and the settings its decisions depend on, as run configs record them."""
        return mode_record(asdict(self))

    def refuse_unused(self, given: Collection[str]) -> None:
        """Refuse, in one line, a setting named in `given` that this config's mode does not use: a
        threshold given to a base run would change nothing, silently."""
        for name in given:
            if name != "mode" and name not in jiti_mode(self.mode).settings:
                flag = next(f.metadata.get("flag") for f in fields(self) if f.name == name) or "--" + name.replace(
                    "_", "-"
                )
                users = [mode for mode in mode_names() if name in jiti_mode(mode).settings]
                raise UserInputError(
                    f"JITI {name} ({flag}) does nothing in mode {self.mode!r} (it shapes mode {', '.join(users)}): "
                    "leave it out"
                )


def mode_record(record: Mapping[str, Any], mode: str | None = None) -> dict[str, Any]:
    """A recorded JITI settings dict cut to `mode`'s settings (default: its own "mode" entry); keys that are
    not settings (the chunk, the policy adapter) stay. Records written before a run recorded only its
    mode's settings held every setting: this reads them as today's record of the same run."""
    mode = record.get("mode") if mode is None else mode
    if mode not in mode_names():  # not a mode: kept whole, so the comparison names what differs
        return dict(record)
    # a run records the settings its mode's decisions depend on (and is compared on them when it resumes or
    # meets a gate), so a base run neither carries nor is refused over settings it never used
    others = set(JITIConfig.settings()) - {"mode", *jiti_mode(mode).settings}
    return {k: v for k, v in record.items() if k not in others}
