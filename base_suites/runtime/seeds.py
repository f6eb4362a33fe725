"""Seeds derived from integer keys, so every piece of randomness has its own reproducible stream."""

from __future__ import annotations

import numpy as np


def derive_seed(*keys: int) -> int:
    """A 32-bit seed from (run seed, task, episode, ...): distinct key tuples give independent streams,
    and the same keys give the same seed in every process (unlike `hash`)."""
    return int(np.random.SeedSequence([int(k) for k in keys]).generate_state(1)[0])
