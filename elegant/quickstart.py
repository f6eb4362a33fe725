"""`elegant quickstart`: the whole chain on one task at small sizes, resumable step by step.

demos (scripted expert, mixed quality) -> annotate (ITC labels) -> train critic (Cal-QL) -> train policy
(BC) -> evaluate base and JITI on identical starts -> side-by-side report. Each step writes its output
atomically and is skipped when that output already exists, so an interrupted quickstart continues where
it stopped.
"""
from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass
from typing import Any



@dataclass(frozen=True)
class QuickstartConfig:
    """Sizes chosen so the chain finishes in minutes on a 2-core CPU."""

    suite: str = "libero_object"
    task: int = 0
    demos: int = 30
    quality: str = "mixed"
    critic_steps: int = 1500
    policy_epochs: int = 40
    episodes: int = 6
    seed: int = 0
    # JITI only picks among candidates within this L2 distance of the base action: with a critic
    # trained on 30 demos, unrestricted re-ranking chose far-off samples and success fell to 0%.
    trust_radius: float = 0.3


def _done(path: str) -> bool:
    return os.path.exists(path)


def quickstart(out: str = "runs/quickstart", config: QuickstartConfig | None = None, progress: bool = True) -> dict[str, Any]:
    """Run (or continue) the chain; returns base vs JITI success and ESR and where the report lies."""
    from annotations import annotate_file
    from base_suites.atomic import atomic_write
    from annotations.collect import collect_demos
    from critics import train_critic
    from elegant.evaluation import evaluate
    from elegant.policies import train_policy
    from elegant.report import compare_runs

    cfg = config or QuickstartConfig()
    os.makedirs(out, exist_ok=True)
    config_path = os.path.join(out, "quickstart.json")
    if os.path.exists(config_path):
        with open(config_path) as f:
            previous = json.load(f)
        if previous != asdict(cfg):
            from base_suites.errors import UserInputError

            raise UserInputError(f"{config_path}: {out} holds a quickstart with other settings; choose another --out")
    atomic_write(config_path, json.dumps(asdict(cfg), indent=2))
    demos = os.path.join(out, "demos.hdf5")
    annotated = os.path.join(out, "annotated.hdf5")
    critic_dir = os.path.join(out, "critic")
    policy_dir = os.path.join(out, "policy")
    runs = {mode: os.path.join(out, f"eval_{mode}") for mode in ("base", "jiti")}

    def say(step: str) -> None:
        if progress:
            print(f"[quickstart] {step}", flush=True)

    if not _done(demos):
        say(f"1/6 demos: {cfg.demos} {cfg.quality}-quality expert episodes on {cfg.suite}/{cfg.task}")
        collect_demos(cfg.suite, [cfg.task], cfg.demos, demos, quality=cfg.quality, seed=cfg.seed, resume=True, progress=progress)
    if not _done(annotated):
        say("2/6 annotate: ITC labels by replaying the demos in the simulator")
        annotate_file(demos, annotated, progress=progress)
    if not _done(os.path.join(critic_dir, "critic.json")):
        say(f"3/6 train critic: Cal-QL, {cfg.critic_steps} steps")
        train_critic([annotated], critic_dir, steps=cfg.critic_steps, seed=cfg.seed, resume=True, progress=progress)
    if not _done(os.path.join(policy_dir, "config.json")):
        say(f"4/6 train policy: BC with a GMM head, {cfg.policy_epochs} epochs")
        train_policy([demos], policy_dir, epochs=cfg.policy_epochs, seed=cfg.seed, resume=True, progress=progress)
    summaries = {}
    for step, mode in ((5, "base"), (6, "jiti")):
        say(f"{step}/6 evaluate {mode}: {cfg.episodes} episodes")
        jiti_kwargs = {"trust_radius": cfg.trust_radius} if mode == "jiti" else None
        summaries[mode] = evaluate(cfg.suite, [cfg.task], policy_dir, critic_dir, mode=mode, episodes=cfg.episodes, seed=cfg.seed,
                                   out=runs[mode], resume=True, progress=progress, jiti_kwargs=jiti_kwargs)
    report_dir = os.path.join(out, "report")
    compare_runs([runs["base"], runs["jiti"]], report_dir)
    result = {
        mode: {k: summaries[mode][k] for k in ("success_rate", "esr", "interventions_per_episode")} for mode in summaries
    }
    result["report"] = os.path.join(report_dir, "comparison.md")
    result["runs"] = runs
    return result
