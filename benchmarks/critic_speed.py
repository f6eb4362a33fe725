"""Speed of the elegance critic: Cal-QL gradient steps and run-time decisions.

Measures, in one run and on the same data, networks and thread count:
  * gradient steps/s of `critics.CalQLLoss` and of TorchRL's stock `CQLLoss` (batch 256, 10 sampled
    actions per kind, twin 256x256 critics, the same tanh-Gaussian actor, Adam, SoftUpdate); target >= 1.5x;
  * our step's FLOPs (counted by dispatching every op through torch's FLOP formulas) times steps/s, as
    a fraction of this CPU's float32 matmul throughput (a square sgemm, measured here); target >= 60%;
  * `Critic.q` latency for 1 state x 16 actions on one thread (median), against its matmul time (its
    FLOPs at the square sgemm's rate measured here); target <= 2x; for reference, the bare module forward
    on ready tensors;
  * where torch sees a GPU, the same step and `Critic.q` there (`Critic.to`) beside the GPU's matmul rate;
    where it sees none, the output says so.
The machine may be shared: every figure is taken over interleaved rounds, and both the best round
(the machine's capability) and the median are reported; ratios compare the same statistic. Targets are
judged on medians.
Last line: one JSON object with the figures.

    python benchmarks/critic_speed.py [--rounds 8] [--steps 3] [--threads 1]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils.flop_counter import flop_registry
from torchrl.data import Bounded
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import CQLLoss, SoftUpdate

from annotations import TaskFeatureEncoder
from critics import CalQLLoss, Critic, Normalization, TanhGaussianActor, TrainConfig, TwinQNetwork, make_replay_buffer

ACTION_DIM = 7


class FlopCount(TorchDispatchMode):
    """Sum of torch's FLOP formulas (matmuls, convolutions) over every op run inside the context."""

    def __init__(self) -> None:
        super().__init__()
        self.total = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        out = func(*args, **kwargs)
        formula = flop_registry.get(func._overloadpacket)
        if formula is not None:
            self.total += formula(*args, **kwargs, out_val=out)
        return out


def random_transitions(n: int, obs_dim: int, seed: int) -> TensorDict:
    """Transitions in the layout of `critics.data` (normalised observations, actions in [-1, 1])."""
    g = torch.Generator().manual_seed(seed)
    done = torch.rand(n, 1, generator=g) < 0.01
    return TensorDict(
        {
            "observation": torch.randn(n, obs_dim, generator=g),
            "action": torch.rand(n, ACTION_DIM, generator=g) * 2 - 1,
            "mc_return": torch.rand(n, 1, generator=g) * 20,
            "next": {
                "observation": torch.randn(n, obs_dim, generator=g),
                "reward": (torch.rand(n, 1, generator=g) < 0.8).float(),
                "done": done,
                "terminated": done,
            },
        },
        batch_size=[n],
    )


def our_loss(obs_dim: int, hidden: list[int], n_actions: int) -> CalQLLoss:
    """Ours at the settings of TorchRL's `CQLLoss` (`stock_loss`): the policy's backup, TD alone, squared
    error, gamma 0.99, so the two losses do the same work per step."""
    cfg = replace(TrainConfig(), n_actions=n_actions, cql_weight=5.0, backup="policy", mc_weight=0.0, value_loss="mse")
    actor, qvalue = TanhGaussianActor(obs_dim, ACTION_DIM, hidden), TwinQNetwork(obs_dim, ACTION_DIM, hidden)
    return CalQLLoss.from_config(actor, qvalue, cfg, gamma=0.99)


def stock_loss(obs_dim: int, hidden: list[int], n_actions: int) -> CQLLoss:
    actor = ProbabilisticActor(
        TensorDictModule(
            TanhGaussianActor(obs_dim, ACTION_DIM, hidden), in_keys=["observation"], out_keys=["loc", "scale"]
        ),
        in_keys=["loc", "scale"],
        distribution_class=TanhNormal,
        spec=Bounded(-1.0, 1.0, (ACTION_DIM,)),
    )
    qvalue = ValueOperator(
        MLP(in_features=obs_dim + ACTION_DIM, out_features=1, num_cells=hidden, activation_class=torch.nn.ReLU),
        in_keys=["observation", "action"],
    )
    loss = CQLLoss(actor, qvalue, num_random=n_actions)
    loss.make_value_estimator(gamma=0.99)
    return loss


def gradient_step(loss: torch.nn.Module, buffer) -> Callable[[], None]:
    """The training step of `critics.train_critic`: sample, all loss_* terms, one backward, Adam, soft update."""
    optimizer = torch.optim.Adam(loss.parameters(), lr=3e-4)
    updater = SoftUpdate(loss, tau=0.005)
    used = ("loss_actor", "loss_qvalue", "loss_cql", "loss_alpha")

    def step() -> None:
        out = loss(buffer.sample())
        optimizer.zero_grad(set_to_none=True)
        sum(out[k] for k in used).backward()
        optimizer.step()
        updater.step()

    return step


def interleaved(tasks: dict[str, Callable[[], None]], rounds: int, repeat: int) -> dict[str, list[float]]:
    """Seconds per call of each task, one round of each in turn (so load changes hit all alike)."""
    times: dict[str, list[float]] = {name: [] for name in tasks}
    for _ in range(rounds):
        for name, task in tasks.items():
            start = time.perf_counter()
            for _ in range(repeat):
                task()
            times[name].append((time.perf_counter() - start) / repeat)
    return times


def q_flops(obs_dim: int, hidden: list[int], actions: int = 16, critics: int = 2) -> int:
    """The multiply-adds (x2) of `Critic.q` for one state: the state part of the first layer once, the
    action part and every later layer per action, for each critic."""
    sizes = [*hidden, 1]
    per_action = ACTION_DIM * hidden[0] + sum(i * o for i, o in zip(sizes[:-1], sizes[1:]))
    return 2 * critics * ((obs_dim - 1) * hidden[0] + actions * per_action)


def q_latency(obs_dim: int, hidden: list[int], calls: int, device: str = "cpu") -> dict[str, list[float]]:
    """Seconds per call for one state and 16 candidate actions (one thread): `Critic.q` from raw numpy
    inputs, and for reference the bare `TwinQNetwork` forward on ready tensors (no encoding, no min)."""
    state_dim = obs_dim - 1
    encoder = TaskFeatureEncoder({"bench/0": [["state", state_dim]]})
    rng = np.random.default_rng(0)
    normalization = Normalization.fit(
        rng.normal(size=(100, obs_dim)), rng.uniform(-1, 1, size=(100, ACTION_DIM)), state_dim
    )
    critic = Critic(TwinQNetwork(obs_dim, ACTION_DIM, hidden), encoder, normalization).to(device)
    critic.bind({"suite": "bench", "task_index": 0, "state_layout": [["state", state_dim]]})
    state, actions = rng.normal(size=state_dim), rng.uniform(-1, 1, size=(16, ACTION_DIM))
    obs, candidates = torch.randn(1, obs_dim, device=device), torch.rand(1, 16, ACTION_DIM, device=device)

    def module() -> None:
        with torch.inference_mode():
            critic.network(obs, candidates).min(0).values.cpu()

    calls_of = {"critic_q": lambda: critic.q(state, actions), "module_forward": module}
    out: dict[str, list[float]] = {name: [] for name in calls_of}
    for _ in range(calls):
        for name, call in calls_of.items():
            start = time.perf_counter()
            call()
            out[name].append(time.perf_counter() - start)
    return out


def latency_summary(seconds: list[float], block: int = 250) -> dict[str, float]:
    """Median and p90 over all calls, and the best median of consecutive blocks of calls (the quietest
    stretch of a shared machine)."""
    us = 1e6 * np.asarray(seconds)
    blocks = [float(np.median(us[i : i + block])) for i in range(0, len(us) - block + 1, block)]
    return {"median": float(np.median(us)), "p90": float(np.percentile(us, 90)), "best_block_median": min(blocks)}


class OnDevice:
    """A replay buffer whose batches are moved to `device` (as `critics.train_critic` moves them)."""

    def __init__(self, buffer, device: str) -> None:
        self.buffer, self.device = buffer, device

    def sample(self) -> TensorDict:
        return self.buffer.sample().to(self.device)


def gpu_figures(args: argparse.Namespace, data: TensorDict, step_flops: int, rounds: int) -> dict | str:
    """The Cal-QL step and `Critic.q` on the first GPU, with its float32 matmul rate; or why there are none."""
    if not torch.cuda.is_available():
        return f"none: torch {torch.__version__} sees no GPU on this machine"
    device = "cuda"
    loss = our_loss(args.obs_dim, args.hidden, args.n_actions).to(device)
    step = gradient_step(loss, OnDevice(make_replay_buffer(data, args.batch, torch.Generator().manual_seed(0)), device))
    a, b = torch.randn(8192, 8192, device=device), torch.randn(8192, 8192, device=device)

    def synced(task: Callable[[], object]) -> Callable[[], None]:
        def run() -> None:
            task()
            torch.cuda.synchronize()

        return run

    for _ in range(5):
        step()
    times = interleaved({"step": synced(step), "matmul": synced(lambda: a @ b)}, rounds, 10)
    median = {k: statistics.median(v) for k, v in times.items()}
    matmul_rate = 2 * 8192**3 / median["matmul"]
    latency = q_latency(args.obs_dim, args.hidden, 1000, device=device)
    return {
        "device": torch.cuda.get_device_name(0),
        "ours_steps_per_s": 1 / median["step"],
        "matmul_gflops": matmul_rate / 1e9,
        "ours_roofline_fraction": step_flops / median["step"] / matmul_rate,
        "q_latency_us": latency_summary(latency["critic_q"]),
        "module_forward_latency_us": latency_summary(latency["module_forward"]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--n-actions", type=int, default=10)
    parser.add_argument("--hidden", type=int, nargs="+", default=[256, 256])
    parser.add_argument(
        "--obs-dim", type=int, default=82, help="encoded observation width (e.g. 72 state dims + 10 tasks)"
    )
    parser.add_argument("--rounds", type=int, default=8)
    parser.add_argument("--steps", type=int, default=3, help="gradient steps per round and loss")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--q-calls", type=int, default=3000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)

    data = random_transitions(20_000, args.obs_dim, args.seed)
    ours = our_loss(args.obs_dim, args.hidden, args.n_actions)
    stock = stock_loss(args.obs_dim, args.hidden, args.n_actions)
    steps = {
        name: gradient_step(loss, make_replay_buffer(data, args.batch, torch.Generator().manual_seed(args.seed)))
        for name, loss in (("ours", ours), ("stock", stock))
    }
    flops = {}
    for name, step in steps.items():
        step()  # warm-up (allocations, lazy initialisation)
        with FlopCount() as count:
            step()
        flops[name] = count.total
    size = 1024
    a, b = torch.randn(size, size), torch.randn(size, size)
    matmul_repeat = max(1, round(flops["ours"] / (2 * size**3)))  # about one of our steps' worth of FLOPs
    times = interleaved({**steps, "matmul": lambda: [a @ b for _ in range(matmul_repeat)]}, args.rounds, args.steps)

    torch.set_num_threads(1)
    latency = q_latency(args.obs_dim, args.hidden, args.q_calls)
    gpu = gpu_figures(args, data, flops["ours"], args.rounds)

    best = {k: min(v) for k, v in times.items()}
    median = {k: statistics.median(v) for k, v in times.items()}
    matmul_flops = matmul_repeat * 2 * size**3
    result = {
        "threads": args.threads,
        "batch": args.batch,
        "n_actions": args.n_actions,
        "hidden": args.hidden,
        "obs_dim": args.obs_dim,
        "ours_steps_per_s": {"best": 1 / best["ours"], "median": 1 / median["ours"]},
        "stock_steps_per_s": {"best": 1 / best["stock"], "median": 1 / median["stock"]},
        "speedup_vs_stock": {"best": best["stock"] / best["ours"], "median": median["stock"] / median["ours"]},
        "ours_gflop_per_step": flops["ours"] / 1e9,
        "stock_gflop_per_step": flops["stock"] / 1e9,
        "matmul_gflops": {"best": matmul_flops / best["matmul"] / 1e9, "median": matmul_flops / median["matmul"] / 1e9},
        "ours_roofline_fraction": {
            "best": flops["ours"] / best["ours"] / (matmul_flops / best["matmul"]),
            "median": flops["ours"] / median["ours"] / (matmul_flops / median["matmul"]),
        },
        "q_latency_us": latency_summary(latency["critic_q"]),
        "q_matmul_time_us": 1e6 * q_flops(args.obs_dim, args.hidden) / (matmul_flops / median["matmul"]),
        "module_forward_latency_us": latency_summary(latency["module_forward"]),
        "gpu": gpu,
    }
    result["q_latency_over_matmul_time"] = result["q_latency_us"]["median"] / result["q_matmul_time_us"]
    result["targets_met"] = {
        "speedup>=1.5": result["speedup_vs_stock"]["median"] >= 1.5,
        "roofline>=0.6": result["ours_roofline_fraction"]["median"] >= 0.6,
        "q_latency<=2x_matmul_time": result["q_latency_over_matmul_time"] <= 2.0,
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
