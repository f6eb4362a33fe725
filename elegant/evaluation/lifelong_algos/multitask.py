"""Multitask: every task's demos at once, no stages (the upper bound; `elegant.evaluation.lifelong`
runs it apart)."""

from __future__ import annotations

from elegant.evaluation.lifelong_algos import LifelongAlgorithm


class Multitask(LifelongAlgorithm):
    name = "multitask"
    title = "multitask training (MTL, the upper bound)"
    position = 4
    staged = False
