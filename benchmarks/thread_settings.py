"""Training speed under each CPU thread setting, on a quiet machine and on a busy one, in one run.

Times gradient steps of the recipe's two trainings (`train-policy`: the BC-GMM network at `BCConfig`'s
defaults; `train-critic`: the Cal-QL step at `TrainConfig`'s defaults) in fresh processes, once with the
machine otherwise idle and once beside `--competitors` CPU-bound processes (default: one per core, as
when other jobs share a workstation). Each setting is a torch intra-op thread count and OpenMP's wait
policy: with "active" (libgomp's default) threads spin at every barrier, which collapses when a
competitor holds one of their cores; "passive" makes them sleep instead. Settings and conditions are
interleaved over `--rounds`; medians are reported, with each setting's busy/quiet ratio and its quiet
rate against the fastest quiet setting. The threads the CLI uses by default (`base_suites.runtime.compute`)
are listed beside them. Prints one JSON object on its last line.

    python benchmarks/thread_settings.py [--seconds 3] [--rounds 2] [--competitors N]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable

WORKLOADS = ("train-policy", "train-critic")


def settings(cores: int) -> dict[str, dict[str, object]]:
    """The thread settings compared: one thread, and one per core with either wait policy."""
    return {
        "1 thread": {"threads": 1, "wait": "active"},
        f"{cores} threads": {"threads": cores, "wait": "active"},
        f"{cores} threads, passive wait": {"threads": cores, "wait": "passive"},
    }


def policy_step() -> Callable[[], None]:
    """One `train-policy` gradient step at the recipe's sizes (history 10 of an 81-wide state, chunk 8)."""
    import torch

    from elegant.policies.bc_config import BCConfig
    from elegant.policies.bc_model import BCNet

    cfg = BCConfig()
    input_dim, action_dim = cfg.history * 91, 7 * cfg.chunk
    net = BCNet(input_dim, hidden=cfg.hidden, action_dim=action_dim, modes=cfg.modes, min_std=cfg.min_std)
    optimizer = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    x, actions = torch.randn(cfg.batch_size, input_dim), torch.rand(cfg.batch_size, action_dim) * 2 - 1

    def step() -> None:
        loss = net.nll(x, actions).mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()

    return step


def critic_step() -> Callable[[], None]:
    """One `train-critic` Cal-QL step at `TrainConfig`'s defaults (an 82-wide encoded state)."""
    import torch
    from critic_speed import ACTION_DIM, gradient_step, random_transitions

    from critics import CalQLLoss, TanhGaussianActor, TrainConfig, TwinQNetwork, make_replay_buffer

    cfg, obs_dim = TrainConfig(), 82
    actor, qvalue = TanhGaussianActor(obs_dim, ACTION_DIM, cfg.hidden), TwinQNetwork(obs_dim, ACTION_DIM, cfg.hidden)
    loss = CalQLLoss.from_config(actor, qvalue, cfg, gamma=cfg.gamma)
    data = random_transitions(20_000, obs_dim, 0)
    return gradient_step(loss, make_replay_buffer(data, cfg.batch_size, torch.Generator().manual_seed(0)))


def worker(workload: str, threads: int, seconds: float) -> None:
    """Print the steps/s of `workload` over `seconds` (after a warm-up) as JSON."""
    import torch

    torch.set_num_threads(threads)
    torch.manual_seed(0)
    step = policy_step() if workload == "train-policy" else critic_step()
    for _ in range(3):
        step()
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        step()
        steps += 1
    print(json.dumps({"steps_per_s": steps / (time.perf_counter() - start)}))


def measure(workload: str, setting: dict[str, object], seconds: float) -> float:
    env = {**os.environ, "OMP_WAIT_POLICY": str(setting["wait"]).upper()}
    env.pop("OMP_NUM_THREADS", None)
    command = [sys.executable, __file__, "--worker", workload, "--threads", str(setting["threads"])]
    out = subprocess.run(
        [*command, "--seconds", str(seconds)],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])["steps_per_s"]


def competing(count: int) -> list[subprocess.Popen]:
    """`count` processes that keep a core busy each (plain Python arithmetic, no threads of their own)."""
    return [subprocess.Popen([sys.executable, "-c", "x = 0\nwhile True:\n    x += 1"]) for _ in range(count)]


def main() -> dict[str, object]:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=3.0, help="timed seconds per measurement")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--competitors", type=int, default=os.cpu_count(), help="CPU-bound processes when busy")
    parser.add_argument("--worker", choices=WORKLOADS, help=argparse.SUPPRESS)
    parser.add_argument("--threads", type=int, default=1, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.worker, args.threads, args.seconds)
        return {}
    from base_suites.runtime.compute import ComputeConfig

    cores = os.cpu_count() or 1
    compared = settings(cores)
    rates: dict[tuple[str, str, str], list[float]] = {}
    for _ in range(args.rounds):
        for condition in ("quiet", "busy"):
            others = competing(args.competitors) if condition == "busy" else []
            try:
                for workload in WORKLOADS:
                    for name, setting in compared.items():
                        rate = measure(workload, setting, args.seconds)
                        rates.setdefault((workload, name, condition), []).append(rate)
            finally:
                for process in others:
                    process.kill()
                    process.wait()
    table: dict[str, dict[str, dict[str, float]]] = {}
    for workload in WORKLOADS:
        rows = {
            name: {c: statistics.median(rates[(workload, name, c)]) for c in ("quiet", "busy")} for name in compared
        }
        best_quiet = max(r["quiet"] for r in rows.values())
        for row in rows.values():
            row["busy_over_quiet"] = row["busy"] / row["quiet"]
            row["quiet_over_best_quiet"] = row["quiet"] / best_quiet
        table[workload] = {name: {k: round(v, 3) for k, v in row.items()} for name, row in rows.items()}
    return {
        "benchmark": "thread_settings",
        "cores": cores,
        "competitors": args.competitors,
        "seconds": args.seconds,
        "rounds": args.rounds,
        "default_threads": ComputeConfig().threads,
        "steps_per_s": table,
    }


if __name__ == "__main__":
    result = main()
    if result:
        print(json.dumps(result))
