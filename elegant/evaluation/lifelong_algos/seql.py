"""SeqL: plain fine-tuning of the kept network on each new task (LIBERO's `Sequential`)."""

from __future__ import annotations

from elegant.evaluation.lifelong_algos import LifelongAlgorithm


class Sequential(LifelongAlgorithm):
    name = "seql"
    title = "sequential fine-tuning (SeqL)"
    position = 0
