"""Mode "base": the base policy acts alone; a critic, if given, still scores every decision for the log."""

from __future__ import annotations

from elegant.intervention.modes import JITIMode, register_mode
from elegant.intervention.selectors import CriticArgmax
from elegant.intervention.triggers import Never

register_mode(
    JITIMode(
        name="base",
        help="never intervene",
        settings=(),
        trigger=lambda config, steps: Never(),
        selector=lambda config: CriticArgmax(config.trust_radius, config.min_gain),
        describe=lambda record, candidates: "JITI: not used (the base policy acts alone)",
        needs_critic=False,
    )
)
