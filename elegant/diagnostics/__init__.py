"""Diagnostics of a trained critic on recorded data, without the simulator: `branch_ranking` (what
`elegant rank-check` prints) measures how well a critic ranks the alternatives JITI chooses among."""

from elegant.diagnostics.branch_ranking import branch_ranking

__all__ = ["branch_ranking"]
