"""A gymnasium wrapper that labels every step with the ITCs.

Adds to `info` after each step: `itc` (step index, per-criterion kept flags, reasons for violations)
and `elegance_reward`; when the episode ends (terminated or truncated) also `itc_verdict` (success,
elegant, violated criteria, window labels, violation steps and events). The task reward is unchanged,
so the wrapper can sit under any training or evaluation loop.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from itc.monitor import ITCMonitor
from itc.params import ITCParams
from itc.spec import ConstraintSpec


class ITCWrapper(gym.Wrapper):
    """Runs an `ITCMonitor` alongside a LIBERO env."""

    def __init__(self, env: gym.Env, spec: ConstraintSpec | None = None, params: ITCParams | None = None) -> None:
        super().__init__(env)
        self.monitor = ITCMonitor(env, spec=spec, params=params)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.monitor.reset()
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        result = self.monitor.step(action)
        info = {**info, "itc": result.to_info(), "elegance_reward": result.reward}
        if terminated or truncated:
            info["itc_verdict"] = self.monitor.verdict(bool(info.get("success", terminated))).to_dict()
        return obs, reward, terminated, truncated, info
