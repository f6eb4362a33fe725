"""Render throughput: the obs="vla" env step against a bare `mujoco.Renderer` on the same scene, in one run.

For each render quality ("libero", the default, and "fast"): env steps/s of `obs="vla"` (two cameras at
`--size` px, physics on the fast path, the observation built) and frames/s of a bare `mujoco.Renderer` that
renders the same two cameras of the same model and state, nothing else; their ratio is the issue's target
(>= 0.9). Also where a step's time goes: the physics alone (a low-dim env), the camera render through
robosuite's observables. Rounds are interleaved, so machine noise hits every rate alike. Says which GL
backend rendered (EGL on a GPU, OSMesa in software).

    python benchmarks/render_throughput.py [--suite libero_object] [--task 0] [--size 256] [--steps 40] [--rounds 3]

Prints one JSON object on its last line.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np

from base_suites import make_env
from base_suites._libero import rendering_backend
from base_suites.env import CAMERA, WRIST_CAMERA
from base_suites.stack import stack_record


def _rate(fn, n: int) -> float:
    start = time.perf_counter()
    for i in range(n):
        fn(i)
    return n / (time.perf_counter() - start)


def main() -> dict:
    import mujoco

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suite", default="libero_object")
    parser.add_argument("--task", type=int, default=0)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    actions = np.random.default_rng(0).uniform(-0.3, 0.3, size=(args.steps, 7))
    lowdim = make_env(args.suite, args.task, init_state=0, max_steps=10**9)
    envs, renderers = {}, {}
    for quality in ("libero", "fast"):
        env = make_env(
            args.suite, args.task, init_state=0, obs="vla", camera_size=args.size, max_steps=10**9,
            render_quality=quality,
        )  # fmt: skip
        envs[quality] = env
        renderers[quality] = mujoco.Renderer(env.domain.sim.model._model, args.size, args.size)
    rates: dict[str, list[float]] = {k: [] for k in ("physics", "env_libero", "env_fast", "bare_libero", "bare_fast")}
    for _ in range(args.rounds):
        lowdim.reset(seed=0)
        rates["physics"].append(_rate(lambda i: lowdim.step(actions[i]), args.steps))
        for quality, env in envs.items():
            env.reset(seed=0)
            rates[f"env_{quality}"].append(_rate(lambda i, env=env: env.step(actions[i]), args.steps))
            renderer, data = renderers[quality], env.domain.sim.data._data

            def frame(i: int, renderer=renderer, data=data) -> None:
                for camera in (CAMERA, WRIST_CAMERA):
                    renderer.update_scene(data, camera=camera)
                    renderer.render()

            rates[f"bare_{quality}"].append(_rate(frame, args.steps))
    median = {k: statistics.median(v) for k, v in rates.items()}
    for env in (lowdim, *envs.values()):
        env.close()
    return {
        "benchmark": "render_throughput",
        "suite": args.suite,
        "task": args.task,
        "size": args.size,
        "gl": rendering_backend(),
        "rates_per_s": {k: round(v, 2) for k, v in median.items()},
        "env_over_bare_libero": round(median["env_libero"] / median["bare_libero"], 3),
        "env_over_bare_fast": round(median["env_fast"] / median["bare_fast"], 3),
        "libero_over_fast": round(median["env_libero"] / median["env_fast"], 3),
        "ms_per_step": {
            "physics": round(1000 / median["physics"], 2),
            "render_libero": round(1000 / median["bare_libero"], 2),
            "render_fast": round(1000 / median["bare_fast"], 2),
        },
        "stack": stack_record(render=None),
    }


if __name__ == "__main__":
    print(json.dumps(main()))
