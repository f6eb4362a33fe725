"""Decision latency of the BC-GMM base policy on one CPU thread.

Targets: one action for one observation <= 1 ms; 16 candidates via `sample` (right after the action, as
JITI asks at a critical moment) <= 2 ms. The policy is trained for one epoch by `train_policy` on a
synthetic dataset whose state layout has the size of a LIBERO scene (robot proprioception plus
`--objects` object poses), with the default network (history 10, 256x256 trunk, 16 modes); latency does
not depend on what the weights learned. Also reports the bare network forward and the adapter overhead
of wrapping a trivial callable, for comparison. Prints one JSON object on its last line (ratio =
median / target; <= 1 meets the target).  Usage: python benchmarks/policy_speed.py [--repeats 2000]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from collections.abc import Callable

import numpy as np
import torch

from annotations import Demo, DemoWriter
from base_suites.env import ROBOT_LAYOUT
from elegant.policies import as_policy, load_policy, train_policy

TARGET_ACTION_MS = 1.0
TARGET_SAMPLE16_MS = 2.0


def _median_ms(fn: Callable[[int], object], repeats: int) -> float:
    times = []
    for i in range(repeats):
        start = time.perf_counter()
        fn(i)
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def _write_dataset(path: str, layout: list[list], steps: int, seed: int) -> str:
    rng = np.random.default_rng(seed)
    width = sum(s for _, s in layout)
    writer = DemoWriter(path, {"env_args": {}, "problem_info": {}})
    for d in range(2):
        obs = rng.normal(size=(steps, width))
        actions = np.clip(rng.normal(0, 0.5, size=(steps, 7)), -1, 1)
        attrs = {"suite": "libero_object", "task_index": 0, "task_name": "synthetic", "success": True}
        writer.append(
            Demo(f"demo_{d}", actions, np.zeros((steps, 1)), obs, obs, np.zeros(steps), np.eye(steps)[-1], attrs),
            state_layout=layout,
        )
    return writer.finish()


def main() -> dict:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument(
        "--objects", type=int, default=7, help="objects in the synthetic scene (7 numbers of pose each)"
    )
    parser.add_argument("--repeats", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    objects = [[f"object_{i}/{part}", size] for i in range(args.objects) for part, size in (("pos", 3), ("quat", 4))]
    layout = [[n, s] for n, s in ROBOT_LAYOUT] + objects
    metadata = {"suite": "libero_object", "task_index": 0, "instruction": "synthetic", "state_layout": layout}

    with tempfile.TemporaryDirectory() as tmp:
        demos = _write_dataset(os.path.join(tmp, "demos.hdf5"), layout, steps=64, seed=args.seed)
        train_policy([demos], os.path.join(tmp, "bc"), epochs=1, seed=args.seed, progress=False)
        policy = load_policy(os.path.join(tmp, "bc"), seed=args.seed)
    policy.reset(metadata)
    states = np.random.default_rng(args.seed + 1).normal(size=(args.repeats, sum(s for _, s in layout)))
    observations = [{"state": s} for s in states]
    for obs in observations[:50]:  # warm-up: allocator, first-call dispatch
        policy(obs)
        policy.sample(obs, 16)

    action_ms = _median_ms(lambda i: policy(observations[i]), args.repeats)

    def step_then_sample(i: int) -> float:
        policy(observations[i])
        start = time.perf_counter()
        policy.sample(observations[i], 16)
        return time.perf_counter() - start

    sample_ms = 1e3 * statistics.median(step_then_sample(i) for i in range(args.repeats))
    encoded = policy.features.encode(states[: policy.features.history], policy.task)
    x = policy.features.flatten_window(torch.from_numpy(encoded).unsqueeze(0))
    with torch.inference_mode():
        forward_ms = _median_ms(lambda i: policy.net(x), args.repeats)
    adapter = as_policy(lambda obs: obs["state"][:7])
    adapter_ms = _median_ms(lambda i: adapter(observations[i]), args.repeats)

    return {
        "benchmark": "policy_speed",
        "threads": torch.get_num_threads(),
        "state_dim": int(states.shape[1]),
        "input_dim": policy.features.input_dim,
        "action_median_ms": round(action_ms, 4),
        "sample16_median_ms": round(sample_ms, 4),
        "network_forward_median_ms": round(forward_ms, 4),
        "callable_adapter_median_ms": round(adapter_ms, 4),
        "target_action_ms": TARGET_ACTION_MS,
        "target_sample16_ms": TARGET_SAMPLE16_MS,
        "action_ratio_to_target": round(action_ms / TARGET_ACTION_MS, 3),
        "sample16_ratio_to_target": round(sample_ms / TARGET_SAMPLE16_MS, 3),
        "meets_targets": action_ms <= TARGET_ACTION_MS and sample_ms <= TARGET_SAMPLE16_MS,
    }


if __name__ == "__main__":
    print(json.dumps(main()))
