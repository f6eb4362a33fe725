"""ITC label quality: does each injected expert knob get caught by the matching criterion, and are clean
successful episodes labelled elegant?

Targets (issue 4): recall >= 95% for collide -> collision, drop -> collision or pose_accuracy,
misplace -> pose_accuracy, tilt -> alignment, wrong_order -> sequence; false alarms on clean successful
episodes <= 5%. An episode counts for a knob only if the expert actually carried the knob out (its
event is recorded; e.g. a `misplace` episode whose grasp failed never placed anything).

Usage:
  python benchmarks/label_quality.py --annotated runs/exp/a.hdf5 [more.hdf5 ...]
  python benchmarks/label_quality.py --collect --suites libero_object,libero_goal --episodes 20 --out runs/labelq
Prints the confusion table (knob x criterion violation rate) and one JSON object on its last line.
"""

from __future__ import annotations

import argparse
import json
import os

import numpy as np

from annotations import CRITERIA, DemoFile, annotate_file
from annotations.collect import collect_demos
from base_suites.experts import KNOBS
from base_suites.runtime.settings import index_list

EXPECTED = {
    "collide": ("collision",),
    "drop": ("collision", "pose_accuracy"),
    "misplace": ("pose_accuracy",),
    "tilt": ("alignment",),
    "wrong_order": ("sequence",),
}
EVENT_PREFIX = {
    "collide": "collide",
    "drop": "drop",
    "misplace": "misplace",
    "tilt": "tilt",
    "wrong_order": "wrong_order",
}


def carried_out(knob: str, events: list[str]) -> bool:
    prefix = EVENT_PREFIX.get(knob)
    return prefix is None or any(e.startswith(prefix) for e in events)


def evaluate(paths: list[str]) -> dict:
    rows: dict[str, list[dict[str, bool]]] = {k: [] for k in ("none",) + KNOBS}
    for path in paths:
        with DemoFile(path, require_labels=True) as f:
            for demo in f:
                violated = {c: bool(np.any(~demo.itc_segments[c])) for c in CRITERIA}
                knobs = [k for k, on in demo.attrs.get("knobs", {}).items() if on]
                events = list(demo.attrs.get("knob_events", []))
                if not knobs:
                    if demo.attrs.get("success"):
                        rows["none"].append(violated)
                    continue
                for knob in knobs:
                    if carried_out(knob, events):
                        rows[knob].append(violated)
    table = {
        k: {c: float(np.mean([r[c] for r in v])) if v else None for c in CRITERIA} | {"n": len(v)}
        for k, v in rows.items()
    }
    recall = {}
    for knob, criteria in EXPECTED.items():
        hits = [any(r[c] for c in criteria) for r in rows[knob]]
        recall[knob] = {"recall": float(np.mean(hits)) if hits else None, "n": len(hits)}
    clean = rows["none"]
    false_alarm = float(np.mean([any(r.values()) for r in clean])) if clean else None
    return {
        "confusion": table,
        "recall": recall,
        "false_alarm_clean_success": false_alarm,
        "n_clean_success": len(clean),
    }


def main() -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--annotated", nargs="*", default=[])
    parser.add_argument("--collect", action="store_true")
    parser.add_argument("--suites", default="libero_object,libero_goal")
    parser.add_argument("--tasks", type=index_list, help="task indices, e.g. 0-4 (default: all)")
    parser.add_argument("--episodes", type=int, default=20, help="per task")
    parser.add_argument("--quality", default="mixed")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="runs/label_quality")
    args = parser.parse_args()
    paths = list(args.annotated)
    if args.collect:
        os.makedirs(args.out, exist_ok=True)
        for suite in args.suites.split(","):
            tasks = list(args.tasks) if args.tasks else None
            demos = os.path.join(args.out, f"{suite}.hdf5")
            annotated = os.path.join(args.out, f"{suite}.annotated.hdf5")
            if not os.path.exists(demos):
                collect_demos(
                    suite, tasks, demos, episodes=args.episodes, quality=args.quality, seed=args.seed, resume=True
                )
            if not os.path.exists(annotated):
                annotate_file(demos, annotated)
            paths.append(annotated)
    result = evaluate(paths)
    print(f"{'knob':12s} {'n':>4s} " + " ".join(f"{c:>13s}" for c in CRITERIA))
    for knob, row in result["confusion"].items():
        cells = " ".join(f"{row[c]:13.2f}" if row[c] is not None else f"{'-':>13s}" for c in CRITERIA)
        print(f"{knob:12s} {row['n']:4d} {cells}")
    out = {
        "benchmark": "label_quality",
        "files": paths,
        **result,
        "targets": {"recall": 0.95, "false_alarm_clean_success": 0.05},
    }
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()
