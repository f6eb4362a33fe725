"""A corpus of bad inputs run through the `elegant` CLI, each classified by what the user gets back.

Every case is one command line with one mistake in it (a non-finite value, a wrong shape, a misplaced
output, a setting that would silently change the experiment, ...). A case is

    clear       refused: non-zero exit, one line on stderr, no traceback, nothing created or changed
    handled     a case that should succeed did, with the expected effect (e.g. --resume on a finished file)
    silent      exit 0 where a refusal was due: the mistake went through
    unclear     refused, but with more than one line, or leaving files behind or changed
    traceback   a Python traceback or a crash (a signal)

`tests/test_bad_inputs.py` runs every case in-process and requires `clear` or `handled`; this script runs
them in subprocesses against any checkout and prints the counts, its last line one JSON object:

    python scripts/bad_input_corpus.py [--checkout DIR] [--scratch DIR]

Fixtures (two expert demos of libero_object/0, their annotation, a one-epoch policy, a five-step critic
and broken copies of the files) are made once with the current checkout's API.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections import Counter
from dataclasses import dataclass

REFUSE = "refuse"


@dataclass(frozen=True)
class Case:
    """One mistake: `argv` (with {placeholders} for fixture paths and the scratch folder `{s}`), and
    what should happen: REFUSE, or the name of a check in `HANDLED`."""

    name: str
    argv: tuple[str, ...]
    expect: str = REFUSE


def _case(name: str, line: str, expect: str = REFUSE) -> Case:
    return Case(name, tuple(line.split()), expect)


EVAL = "eval --suite libero_object --tasks 0 --policy {policy} --critic {critic} --episodes 1 --max-steps 5"
DEMOS = "demos --suite libero_object --tasks 0 --episodes 1"
LIFELONG = "lifelong --suite libero_object {demos} --epochs 5 --episodes 1"
ROBUST = "robustness --suite libero_object --tasks 0 --episodes 1 --max-steps 5"
CASES = (
    # demos: settings
    Case("demos --tasks ''", ("demos", "--suite", "libero_object", "--tasks", "", "--out", "{s}/t.hdf5")),
    _case("demos --tasks 0,0", "demos --suite libero_object --tasks 0,0 --episodes 1 --out {s}/t.hdf5"),
    _case("demos --tasks 99", "demos --suite libero_object --tasks 99 --out {s}/t.hdf5"),
    _case("demos --suite unknown", "demos --suite libero_nope --out {s}/t.hdf5"),
    _case("demos --seed -5", f"{DEMOS} --seed -5 --out {{s}}/t.hdf5"),
    _case("demos --episodes 0", "demos --suite libero_object --tasks 0 --episodes 0 --out {s}/t.hdf5"),
    _case("demos --quality unknown", f"{DEMOS} --quality bogus --out {{s}}/t.hdf5"),
    _case("demos --workers 0", f"{DEMOS} --workers 0 --out {{s}}/t.hdf5"),
    # demos: outputs
    _case("demos --out an existing file", f"{DEMOS} --out {{demos}}"),
    _case("demos --out a directory", f"{DEMOS} --out {{s}}"),
    _case("demos --out under a file", f"{DEMOS} --out {{s}}/note.txt/t.hdf5"),
    Case("demos --out ''", ("demos", "--suite", "libero_object", "--tasks", "0", "--out", "")),
    _case("demos --resume --overwrite", f"{DEMOS} --resume --overwrite --out {{s}}/t.hdf5"),
    _case(
        "demos --resume on a finished file",
        "demos --suite libero_object --tasks 0 --episodes 2 --seed 0 --quality clean --resume --out {demos}",
        "unchanged",
    ),  # fmt: skip
    # annotate
    _case("annotate NaN actions", "annotate {nan_actions} --out {s}/a.hdf5"),
    _case("annotate inf states", "annotate {inf_states} --out {s}/a.hdf5"),
    _case("annotate 4-D actions", "annotate {actions_4d} --out {s}/a.hdf5"),
    _case("annotate actions shorter than states", "annotate {short_actions} --out {s}/a.hdf5"),
    _case("annotate a missing file", "annotate {s}/missing.hdf5 --out {s}/a.hdf5"),
    _case("annotate a text file", "annotate {s}/note.txt --out {s}/a.hdf5"),
    _case("annotate --gamma nan", "annotate {demos} --gamma nan --out {s}/a.hdf5"),
    _case("annotate --gamma 2", "annotate {demos} --gamma 2 --out {s}/a.hdf5"),
    _case("annotate --labels not UTF-8", "annotate {demos} --labels {latin1_csv} --out {s}/a.hdf5"),
    _case("annotate --labels conflicting rows", "annotate {demos} --labels {conflict_csv} --out {s}/a.hdf5"),
    _case("annotate --out its input", "annotate {demos} --out {demos}"),
    _case("annotate --out an existing file", "annotate {demos} --out {annotated}"),
    # train-policy
    _case("train-policy NaN actions", "train-policy {nan_actions} --epochs 1 --out {s}/p"),
    _case("train-policy inf states", "train-policy {inf_states} --epochs 1 --out {s}/p"),
    _case("train-policy --hidden 8-11", "train-policy {demos} --epochs 1 --hidden 8-11 --out {s}/p"),
    _case("train-policy --lr nan", "train-policy {demos} --epochs 1 --lr nan --out {s}/p"),
    _case("train-policy --epochs 0", "train-policy {demos} --epochs 0 --out {s}/p"),
    _case("train-policy --out an existing policy", "train-policy {demos} --epochs 1 --out {policy}"),
    _case("train-policy --out a file", "train-policy {demos} --epochs 1 --out {s}/note.txt"),
    # train-critic
    _case("train-critic NaN actions", "train-critic {nan_annotated} --steps 2 --out {s}/c"),
    _case("train-critic --cql-weight nan", "train-critic {annotated} --steps 2 --cql-weight nan --out {s}/c"),
    _case("train-critic --steps 0", "train-critic {annotated} --steps 0 --out {s}/c"),
    _case("train-critic unannotated demos", "train-critic {demos} --steps 2 --out {s}/c"),
    _case("train-critic --gamma 1.5", "train-critic {annotated} --steps 2 --gamma 1.5 --out {s}/c"),
    _case("train-critic --out an existing critic", "train-critic {annotated} --steps 2 --out {critic}"),
    # eval
    _case("eval --threshold nan", f"{EVAL} --threshold nan --out {{s}}/e"),
    _case("eval --trust-radius nan", f"{EVAL} --trust-radius nan --out {{s}}/e"),
    _case("eval --max-steps 0", f"{EVAL} --max-steps 0 --out {{s}}/e"),
    _case("eval --max-steps -5", f"{EVAL} --max-steps -5 --out {{s}}/e"),
    _case("eval --candidates huge", f"{EVAL} --candidates 1000000000000 --out {{s}}/e"),
    _case("eval --episodes 0", f"{EVAL} --episodes 0 --out {{s}}/e"),
    _case("eval --init-states 999", f"{EVAL} --init-states 999 --out {{s}}/e"),
    _case("eval --policy missing", f"{EVAL} --policy {{s}}/missing --out {{s}}/e"),
    _case("eval --critic a file", f"{EVAL} --critic {{s}}/note.txt --out {{s}}/e"),
    _case("eval --out a file", f"{EVAL} --out {{s}}/note.txt"),
    # rollouts, import, specs, report
    _case(
        "rollouts --explore 2",
        "rollouts --suite libero_object --tasks 0 --policy {policy} --explore 2 --out {s}/r.hdf5",
    ),  # fmt: skip
    _case("rollouts --policy missing", "rollouts --suite libero_object --tasks 0 --policy {s}/no --out {s}/r.hdf5"),
    _case("import-libero a missing file", "import-libero {s}/missing.hdf5 --out {s}/i.hdf5"),
    _case("import-libero a text file", "import-libero {s}/note.txt --out {s}/i.hdf5"),
    _case("itc-spec task 99", "itc-spec libero_object 99"),
    _case("tasks an unknown suite", "tasks libero_nope"),
    _case("report a missing run", "report {s}/missing"),
    # lifelong and its table
    _case("lifelong --tasks 0,0", f"{LIFELONG} --tasks 0,0 --out {{s}}/l"),
    _case("lifelong --seeds 1,1", f"{LIFELONG} --tasks 0 --seeds 1,1 --out {{s}}/l"),
    _case("lifelong --ewc-lambda nan", f"{LIFELONG} --tasks 0 --algo ewc --ewc-lambda nan --out {{s}}/l"),
    _case("lifelong --packnet-prune 1.5", f"{LIFELONG} --tasks 0 --algo packnet --packnet-prune 1.5 --out {{s}}/l"),
    _case("lifelong --pretrained missing", f"{LIFELONG} --tasks 0 --pretrained {{s}}/no --out {{s}}/l"),
    _case("lifelong --tasks of no demos", f"{LIFELONG} --tasks 1 --out {{s}}/l"),
    _case("lifelong --out a file", f"{LIFELONG} --tasks 0 --out {{s}}/note.txt"),
    _case("lifelong-table a missing run", "lifelong-table {s}/missing --out {s}/t"),
    # robustness, gate, rank-check, quickstart, serve-policy
    _case("robustness --axes unknown", f"{ROBUST} --policy {{policy}} --axes bogus --out {{s}}/rb"),
    _case("robustness --policy missing", f"{ROBUST} --policy {{s}}/no --out {{s}}/rb"),
    _case("gate missing runs", "gate {s}/missing_base {s}/missing_jiti --out {s}/g.json"),
    _case("rank-check rollouts missing", "rank-check --policy {policy} --critic {critic} {s}/missing.hdf5"),
    _case("quickstart --task 99", "quickstart --task 99 --out {s}/q"),
    _case("serve-policy a missing policy", "serve-policy {s}/no"),
)


def make_fixtures(scratch: str) -> dict[str, str]:
    """Real small inputs and broken copies of them, in `scratch`; returns the placeholders' values."""
    import h5py
    import numpy as np

    from annotations import annotate_file
    from annotations.collect import collect_demos
    from critics import train_critic
    from elegant.policies import train_policy

    paths = {"s": scratch}
    paths["demos"] = collect_demos(
        "libero_object", [0], os.path.join(scratch, "demos.hdf5"), episodes=2, seed=0, quality="clean", progress=False
    )["out"]
    paths["annotated"] = os.path.join(scratch, "annotated.hdf5")
    annotate_file(paths["demos"], paths["annotated"], progress=False)
    paths["policy"] = os.path.join(scratch, "policy")
    train_policy([paths["demos"]], paths["policy"], epochs=1, hidden=(32,), progress=False)
    paths["critic"] = os.path.join(scratch, "critic")
    train_critic([paths["annotated"]], paths["critic"], steps=5, progress=False)

    def broken(name: str, source: str, change) -> None:
        paths[name] = os.path.join(scratch, f"{name}.hdf5")
        shutil.copy(source, paths[name])
        with h5py.File(paths[name], "a") as f:
            change(f["data/demo_1"])

    def replace(group, key, values) -> None:
        del group[key]
        group.create_dataset(key, data=values)

    broken("nan_actions", paths["demos"], lambda g: g["actions"].__setitem__((3, 0), np.nan))
    broken("nan_annotated", paths["annotated"], lambda g: g["actions"].__setitem__((3, 0), np.nan))
    broken("inf_states", paths["demos"], lambda g: g["states"].__setitem__((2, 5), np.inf))
    broken("actions_4d", paths["demos"], lambda g: replace(g, "actions", g["actions"][()][:, :4]))
    broken("short_actions", paths["demos"], lambda g: replace(g, "actions", g["actions"][()][:-3]))
    with open(os.path.join(scratch, "note.txt"), "w") as f:
        f.write("not an HDF5 file\n")
    paths["latin1_csv"] = os.path.join(scratch, "labels_latin1.csv")
    with open(paths["latin1_csv"], "wb") as f:
        f.write("demo,start_frame,end_frame,criterion,label\ndemo_0,0,24,collision,1 \xe9\n".encode("latin-1"))
    paths["conflict_csv"] = os.path.join(scratch, "labels_conflict.csv")
    with open(paths["conflict_csv"], "w") as f:
        f.write("demo,start_frame,end_frame,criterion,label\ndemo_0,0,24,collision,1\ndemo_0,0,24,collision,0\n")
    return paths


def snapshot(folder: str) -> dict[str, tuple[int, int]]:
    """Every path under `folder` with its size and modification time."""
    out = {}
    for root, dirs, files in os.walk(folder):
        for name in dirs + files:
            path = os.path.join(root, name)
            stat = os.stat(path)
            out[os.path.relpath(path, folder)] = (stat.st_size, stat.st_mtime_ns)
    return out


def message_lines(stderr: str) -> list[str]:
    """The lines a person reads: without robosuite's import warnings and progress bars."""
    return [
        line
        for line in stderr.splitlines()
        if line.strip() and not line.startswith("[robosuite WARNING]") and "%|" not in line
    ]


HANDLED = {"unchanged": lambda before, after, code: code == 0 and before == after}


def classify(case: Case, code: int, stderr: str, before: dict, after: dict) -> str:
    if "Traceback (most recent call last)" in stderr or code < 0 or code > 2:
        return "traceback"
    if case.expect != REFUSE:
        return "handled" if HANDLED[case.expect](before, after, code) else "silent"
    if code == 0:
        return "silent"
    return "clear" if len(message_lines(stderr)) == 1 and before == after else "unclear"


def argv_of(case: Case, paths: dict[str, str]) -> list[str]:
    return [arg.format(**paths) for arg in case.argv]


def run_subprocess(case: Case, paths: dict[str, str], checkout: str) -> tuple[int, str]:
    env = {**os.environ, "PYTHONPATH": checkout, "OMP_NUM_THREADS": "1"}
    cli = "import sys; from elegant.cli import main; sys.exit(main())"
    command = [sys.executable, "-c", cli, *argv_of(case, paths)]
    done = subprocess.run(command, capture_output=True, text=True, env=env, cwd=checkout, timeout=600)
    return done.returncode, done.stderr


def main() -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkout", default=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    parser.add_argument("--scratch", help="folder for the fixtures, emptied first (default: a temporary one)")
    args = parser.parse_args()
    scratch = args.scratch or tempfile.mkdtemp(prefix="bad-inputs-")
    shutil.rmtree(scratch, ignore_errors=True)
    os.makedirs(scratch)
    paths = make_fixtures(scratch)
    pristine = snapshot(scratch)
    backup = tempfile.mkdtemp(prefix="bad-inputs-pristine-")
    shutil.copytree(scratch, backup, dirs_exist_ok=True)
    results = {}
    for case in CASES:
        before = snapshot(scratch)
        code, stderr = run_subprocess(case, paths, os.path.abspath(args.checkout))
        results[case.name] = classify(case, code, stderr, before, snapshot(scratch))
        shown = (message_lines(stderr) or [""])[-1][:150]
        print(f"{results[case.name]:9s} {case.name}: exit {code}: {shown}", flush=True)
        if snapshot(scratch) != pristine:  # the next case starts from the same fixtures
            shutil.rmtree(scratch)
            shutil.copytree(backup, scratch)
    counts = Counter(results.values())
    summary = {"benchmark": "bad_input_corpus", "checkout": os.path.abspath(args.checkout), "cases": len(CASES)}
    summary.update({k: counts.get(k, 0) for k in ("clear", "handled", "silent", "unclear", "traceback")})
    print(json.dumps(summary))
    return summary


if __name__ == "__main__":
    main()
