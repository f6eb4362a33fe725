"""What wrapping a VLA-style policy costs: the VLA observation and a policy served over openpi's protocol.

In one run, interleaved: env steps/s with `obs="vla"` (two cameras at `--camera-size`) against low-dim;
the time per decision of a `train-policy` policy served by `elegant serve-policy` on localhost and
reached through openpi-client, against the same policy in-process, for a plan and for `--candidates`
sampled chunks (target: the network adds at most 5 ms per decision). Prints one JSON object last.

    python benchmarks/vla_serving.py POLICY_DIR [--suite libero_object] [--task 0] [--steps 40]
"""

from __future__ import annotations

import argparse
import json
import threading
import time

import numpy as np

from base_suites import make_env
from elegant.policies import load_policy
from elegant.policies.remote import OpenPIPolicy
from elegant.policies.server import serve_policy


def _steps_per_second(env, actions) -> float:
    start = time.perf_counter()
    for action in actions:
        env.step(action)
    return len(actions) / (time.perf_counter() - start)


def _per_call_ms(call, observations) -> float:
    start = time.perf_counter()
    for obs in observations:
        call(obs)
    return 1000 * (time.perf_counter() - start) / len(observations)


def main() -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policy", help="a train-policy directory of the task")
    parser.add_argument("--suite", default="libero_object")
    parser.add_argument("--task", type=int, default=0)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--camera-size", type=int, default=256)
    parser.add_argument("--candidates", type=int, default=16)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    actions = np.random.default_rng(0).uniform(-0.3, 0.3, size=(args.steps, 7))
    envs = {mode: make_env(args.suite, args.task, init_state=0, obs=mode, max_steps=10**6, camera_size=args.camera_size)
            for mode in ("lowdim", "vla")}  # fmt: skip
    rates: dict[str, list[float]] = {mode: [] for mode in envs}
    observations = []
    for _ in range(args.rounds):
        for mode, env in envs.items():
            env.reset(seed=0)
            rates[mode].append(_steps_per_second(env, actions))
    env = envs["vla"]
    obs, _ = env.reset(seed=0)
    for action in actions:
        observations.append(obs)
        obs = env.step(action)[0]
    metadata = env.metadata
    for env in envs.values():
        env.close()

    ready, address = threading.Event(), []
    threading.Thread(
        target=serve_policy,
        kwargs={"path": args.policy, "port": 0, "ready": lambda a: (address.append(a), ready.set())},
        daemon=True,
    ).start()
    ready.wait(60)
    policies = {"served": OpenPIPolicy(address[0]), "in_process": load_policy(args.policy)}
    timing: dict[str, dict[str, list[float]]] = {name: {"plan": [], "samples": []} for name in policies}
    for _ in range(args.rounds):
        for name, policy in policies.items():
            policy.reset(metadata, seed=0)
            timing[name]["plan"].append(_per_call_ms(policy.plan, observations))
            timing[name]["samples"].append(
                _per_call_ms(lambda o, p=policy: p.sample_plans(o, args.candidates), observations)
            )
    median = {name: {k: float(np.median(v)) for k, v in t.items()} for name, t in timing.items()}
    added = {k: median["served"][k] - median["in_process"][k] for k in ("plan", "samples")}
    result = {
        "benchmark": "vla_serving",
        "task": f"{args.suite}/{args.task}",
        "rounds": args.rounds,
        "camera_size": args.camera_size,
        "lowdim_steps_per_s": round(float(np.median(rates["lowdim"])), 1),
        "vla_steps_per_s": round(float(np.median(rates["vla"])), 1),
        "vla_over_lowdim": round(float(np.median(rates["vla"]) / np.median(rates["lowdim"])), 3),
        "decision_ms": {name: {k: round(v, 3) for k, v in m.items()} for name, m in median.items()},
        "network_added_ms": {k: round(v, 3) for k, v in added.items()},
        "target_network_added_ms": 5.0,
        "candidates_per_decision": args.candidates,
        "candidate_source": policies["served"].candidate_source,
    }
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
