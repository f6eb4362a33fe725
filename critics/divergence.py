"""Training stops, naming the step, when its loss or weights stop being finite: never a NaN model on disk.

Checked before every checkpoint and before the final save (NaN propagates: weights that went non-finite
stay so), so the last checkpoint on disk is always a finite one to resume from or inspect.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch

from base_suites.runtime.errors import UserInputError


def refuse_divergence(command: str, when: str, losses: Mapping[str, float], module: torch.nn.Module) -> None:
    """Raise a one-line error if any of `losses` or any weight of `module` is NaN or infinite; `when` names
    the point of training ("step 400", "epoch 3")."""
    bad = [name for name, value in losses.items() if not math.isfinite(value)]
    if not bad and all(bool(torch.isfinite(p).all()) for p in module.parameters()):
        return
    raise UserInputError(
        f"{command}: training diverged at {when} (non-finite {', '.join(bad) or 'weights'}); nothing was saved "
        "past the last checkpoint: check the data and settings, or lower the learning rate"
    )
