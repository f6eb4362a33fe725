"""Several independently trained critics scored together, so JITI can ask whether they agree.

One critic's ranking of a policy's alternatives on new starts is only a little better than chance
(`elegant rank-check`), and its confident-looking
overrides of a good plan are where JITI loses elegance. Critics trained on different resamples of the
data (`train_critic(..., bootstrap=seed)`) err differently where the data says little, and agree where
it is clear; critics that differ only in their network seed make the same mistakes.
`CriticEnsemble` scores a state's candidates with every member: `q` is their mean (the value JITI's
window watches), and `member_q` gives each member's scores so a selection rule can demand that every
member prefers an alternative to the base plan before overriding it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from base_suites.runtime.errors import UserInputError
from critics.artifact import load


class CriticEnsemble:
    """Critics with the same chunk length, scored together; a drop-in critic (`bind`, `q`, `chunk`)."""

    def __init__(self, members: Sequence[Any]) -> None:
        if len(members) < 2:
            raise UserInputError(f"a critic ensemble needs at least 2 critics, got {len(members)}")
        chunks = {int(getattr(m, "chunk", 1)) for m in members}
        if len(chunks) != 1:
            paths = ", ".join(f"{getattr(m, 'path', '?')} (chunk {getattr(m, 'chunk', 1)})" for m in members)
            raise UserInputError(f"the critics of an ensemble must score chunks of one length; got {paths}")
        self.members = list(members)
        self.chunk = chunks.pop()
        self.path = ",".join(str(getattr(m, "path", "critic")) for m in self.members)

    def bind(self, metadata: Mapping[str, Any]) -> CriticEnsemble:
        """Bind every member to the env's task (each refuses a task it cannot encode). Goal-relative members
        share one episode plan, so a decision's state is encoded once for all of them."""
        shared = None
        for member in self.members:
            goal_relative = getattr(getattr(member, "encoder", None), "kind", None) == "goal-relative"
            if goal_relative and shared is not None:
                member.bind(metadata, context=shared)
                continue
            member.bind(metadata)  # any critic-like member: bind, q, chunk
            if goal_relative:
                shared = member.context
        return self

    def to(self, device: Any) -> CriticEnsemble:
        """Score every member on `device` (`Critic.to`)."""
        for member in self.members:
            member.to(device)
        return self

    def member_q(self, state: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Every member's Q of the actions: shape (members,) + the shape one critic's `q` returns."""
        return np.stack([np.asarray(m.q(state, actions), dtype=np.float64) for m in self.members])

    def q(self, state: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """The members' mean Q: the shape one critic's `q` returns."""
        return self.member_q(state, actions).mean(axis=0)


def load_ensemble(paths: Sequence[str]) -> CriticEnsemble:
    """The critics in these directories (each `critics.load`) as one ensemble."""
    return CriticEnsemble([load(path) for path in paths])
