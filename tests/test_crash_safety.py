"""Demo files survive kills, full disks and second writers (`annotations.dataset.DemoWriter`, the one writer
of demos, annotate, rollouts and imports; `base_suites.runtime.locks`).

A child process writes synthetic demos; strace kills it at chosen write, sync, rename and unlink calls; a
resumed run must then publish a file equal to an uninterrupted one, and no kill may leave a published file
that does not read back."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap

import h5py
import numpy as np
import pytest

from annotations.dataset import Demo, DemoFile, DemoWriter
from base_suites.runtime import UserInputError

DEMOS = 4
WRITER = textwrap.dedent(
    """
    import sys
    sys.path.insert(0, {tests!r})
    from test_crash_safety import write_demos
    write_demos(sys.argv[1], resume=sys.argv[2] == "1")
    """
).format(tests=os.path.dirname(__file__))
CALLS = ("write", "fsync", "rename", "unlink")  # data, durability, publication, clean-up


def synthetic_demo(i: int) -> Demo:
    rng = np.random.default_rng(i)
    t = 30 + 7 * i
    states = rng.normal(size=(t, 12))
    return Demo(
        name="",
        actions=rng.uniform(-1, 1, size=(t, 7)),
        states=states,
        obs=states[:, :9],
        next_obs=states[:, 3:],
        rewards=np.eye(t)[-1],
        dones=np.eye(t)[-1],
        attrs={"suite": "libero_object", "task_index": i % 2, "init_state_index": i, "knobs": {"tilt": i / 10}},
    )


def write_demos(out: str, resume: bool = False, count: int = DEMOS) -> str:
    writer = DemoWriter(out, {"env_args": {"env_name": "libero"}, "problem_info": {"n": 1}}, resume=resume)
    try:
        for i in range(writer.count, count):
            writer.append(synthetic_demo(i), [["state", 12]])
    except BaseException:
        writer.abandon()
        raise
    return writer.finish()


def file_contents(path: str) -> dict:
    """Every dataset and attribute of an HDF5 file, by path."""
    out = {}

    def visit(name, node):
        out[name] = node[()].tolist() if isinstance(node, h5py.Dataset) else None
        out.update({f"{name}@{k}": np.asarray(v).tolist() for k, v in node.attrs.items()})

    with h5py.File(path, "r") as h5:
        h5.visititems(visit)
        out.update({f"/@{k}": np.asarray(v).tolist() for k, v in h5.attrs.items()})
    return out


def run_writer(out: str, resume: bool, kill_at: tuple[str, int] | None = None, trace: str | None = None):
    """Run the writer in a child; `kill_at` (call, n): strace kills it at its n-th call of that name."""
    command = [sys.executable, "-c", WRITER, out, "1" if resume else "0"]
    if kill_at is not None or trace is not None:
        strace = ["strace", "-f", "-qq", "-e", f"trace={','.join(CALLS)}", "-o", trace or os.devnull]
        if kill_at is not None:
            strace += ["-e", f"inject={kill_at[0]}:signal=KILL:when={kill_at[1]}"]
        command = strace + command
    return subprocess.run(command, capture_output=True, text=True, timeout=120)


@pytest.mark.skipif(shutil.which("strace") is None, reason="needs strace (scripts/setup.sh installs it)")
def test_a_kill_at_any_write_loses_only_the_demo_in_flight_and_resume_completes_the_file(tmp_path):
    reference = str(tmp_path / "reference.hdf5")
    trace = str(tmp_path / "calls.txt")
    assert run_writer(str(tmp_path / "warm-up.hdf5"), resume=False).returncode == 0  # caches bytecode: same calls
    assert run_writer(reference, resume=False, trace=trace).returncode == 0
    with open(trace) as f:  # strace counts each call by name: kill at points spread over each one's calls
        names = [line.split(None, 1)[1].split("(", 1)[0] for line in f if "(" in line and "resumed>" not in line]
    counts = {call: names.count(call) for call in CALLS}
    assert counts["write"] >= DEMOS + 2 and counts["rename"] >= DEMOS + 2, counts  # header, demos, final file
    spread = {"write": 5, "fsync": 3, "rename": 3, "unlink": 1}
    kill_points = [
        (call, int(n)) for call, k in spread.items() for n in sorted(set(np.linspace(1, counts[call], k).astype(int)))
    ]
    expected = file_contents(reference)
    published_early = missed = 0
    for when in kill_points:
        out = str(tmp_path / f"killed_{when[0]}_{when[1]}.hdf5")
        killed = run_writer(out, resume=False, kill_at=when)
        missed += killed.returncode == 0  # a call count that differs by one from the traced run's
        if os.path.exists(out):  # killed after publishing (or not at all): the file must be whole
            published_early += 1
            assert file_contents(out) == expected
            continue
        resumed = run_writer(out, resume=True)
        assert resumed.returncode == 0, f"kill at {when}: {resumed.stderr[-500:]}"
        assert file_contents(out) == expected, f"kill at {when} of {counts}"
        assert not os.path.exists(out + ".partial") and not os.path.exists(out + ".lock")
    assert missed <= 2 and published_early < len(kill_points) // 2  # the kills hit, and hit the writing


def test_resume_drops_a_cut_off_demo_and_stray_files_then_continues(tmp_path):
    out = str(tmp_path / "demos.hdf5")
    reference = write_demos(str(tmp_path / "reference.hdf5"))
    writer = DemoWriter(out, {"env_args": {"env_name": "libero"}, "problem_info": {"n": 1}})
    for i in range(2):
        writer.append(synthetic_demo(i), [["state", 12]])
    writer.abandon()
    journal = out + ".partial"
    with open(os.path.join(journal, "demo_2.h5"), "wb") as f:  # a demo cut off mid-write (e.g. a full disk)
        f.write(b"\x89HDF\r\n\x1a\n" + b"\0" * 100)
    open(os.path.join(journal, ".demo_3.h5.tmp"), "wb").close()
    resumed = DemoWriter(out, {}, resume=True)
    assert resumed.count == 2 and sorted(os.listdir(journal)) == ["demo_0.h5", "demo_1.h5", "header.h5"]
    resumed.abandon()
    write_demos(out, resume=True)
    assert file_contents(out) == file_contents(reference)
    with DemoFile(out) as done:  # the published file as readers see it
        assert [d.attrs["init_state_index"] for d in done] == list(range(DEMOS))
        assert done.state_layouts == {synthetic_demo(i).task_key: [["state", 12]] for i in range(2)}
        assert done.attrs["total"] == sum(synthetic_demo(i).num_samples for i in range(DEMOS))
        np.testing.assert_array_equal(done.demo("demo_3").actions, synthetic_demo(3).actions)


def test_a_fresh_run_over_an_interrupted_file_is_refused_and_keeps_its_demos(tmp_path, capsys):
    """An interrupted writer's journal `<out>.partial` is part of the output: a command writing `out` without
    --resume or --overwrite is refused in one line before any work, so it does not start afresh and delete
    the finished demos; the journal stays byte for byte and --resume then completes the file."""
    from base_suites.runtime.outputs import check_output
    from elegant.cli import main

    out = str(tmp_path / "demos.hdf5")
    reference = write_demos(str(tmp_path / "reference.hdf5"))
    writer = DemoWriter(out, {"env_args": {"env_name": "libero"}, "problem_info": {"n": 1}})
    for i in range(2):
        writer.append(synthetic_demo(i), [["state", 12]])
    writer.abandon()  # interrupted after two demos; no `out` yet
    journal = out + ".partial"

    def journal_files() -> dict[str, bytes]:
        return {name: open(os.path.join(journal, name), "rb").read() for name in sorted(os.listdir(journal))}

    before = journal_files()
    assert sorted(before) == ["demo_0.h5", "demo_1.h5", "header.h5"] and not os.path.exists(out)
    refusal = f"{journal}: exists; pass --resume to continue it, --overwrite to replace it, or choose another path"
    for command in (
        ["demos", "--suite", "libero_object", "--tasks", "0", "--episodes", "1", "--out", out],
        ["annotate", reference, "--out", out],
    ):
        assert main(command) == 2, command[0]
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and refusal in err, err
    with pytest.raises(UserInputError, match="demos.hdf5.partial: exists; pass --resume"):
        check_output(out, "file")  # the rule every file-writing command applies (demos, rollouts, annotate)
    assert journal_files() == before and not os.path.exists(out)
    write_demos(out, resume=True)  # the interrupted run's two demos, then the other two
    assert file_contents(out) == file_contents(reference)


def test_a_second_writer_of_the_same_file_is_refused_naming_the_first(tmp_path):
    out = str(tmp_path / "demos.hdf5")
    first = DemoWriter(out, {})
    try:
        with pytest.raises(UserInputError, match=rf"demos.hdf5: in use by another run \(pid {os.getpid()} on "):
            DemoWriter(out, {}, resume=True)
        first.append(synthetic_demo(0), [["state", 12]])
    finally:
        first.finish()
    with DemoFile(out) as done:  # the refused writer changed nothing
        assert done.names == ["demo_0"]
    DemoWriter(out, {}).abandon()  # released on finish: a later writer gets the lock


def test_a_full_disk_keeps_the_finished_demos_for_resume(tmp_path, monkeypatch):
    out = str(tmp_path / "demos.hdf5")
    writer = DemoWriter(out, {"env_args": {"env_name": "libero"}, "problem_info": {"n": 1}})
    writer.append(synthetic_demo(0), [["state", 12]])
    real_fsync = os.fsync

    def disk_full(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", disk_full)
    with pytest.raises(OSError, match="No space left"):
        writer.append(synthetic_demo(1), [["state", 12]])
    writer.abandon()
    monkeypatch.setattr(os, "fsync", real_fsync)
    assert sorted(os.listdir(out + ".partial")) == ["demo_0.h5", "header.h5"]
    write_demos(out, resume=True)
    assert file_contents(out) == file_contents(write_demos(str(tmp_path / "reference.hdf5")))


def test_a_running_eval_holds_its_run_directory(tmp_path):
    from base_suites.runtime.locks import output_lock
    from elegant.evaluation.runner import evaluate

    out = tmp_path / "run"
    with output_lock(out):
        with pytest.raises(UserInputError, match="run: in use by another run"):
            evaluate("libero_object", [0], lambda obs: np.zeros(7), mode="base", out=out, episodes=1, progress=False)
    assert not out.exists() or not any(out.iterdir())  # the refused run wrote nothing


def test_atomic_files_follow_the_umask_and_printed_json_stays_json(tmp_path, capsys):
    import json

    from base_suites.runtime import atomic_write
    from elegant.cli import _print_json

    previous = os.umask(0o027)
    try:
        atomic_write(tmp_path / "a.json", "{}")
    finally:
        os.umask(previous)
    assert os.stat(tmp_path / "a.json").st_mode & 0o777 == 0o640
    _print_json({"rate": float("nan"), "per_task": [1.0, float("inf")]})
    printed = capsys.readouterr().out
    assert json.loads(printed) == {"rate": None, "per_task": [1.0, None]} and '"per_task": [1.0, null]' in printed


def test_a_real_full_disk_keeps_the_finished_demos_and_resume_completes_the_file(tmp_path):
    """On a 1 MB tmpfs (where this process may mount one): a filler leaves room for about two demos; the
    writer fails with a plain OSError naming its file, keeps what finished, and completes once space is freed."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(disk)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here (the injected-ENOSPC test covers the writer)")
    try:
        filler = disk / "filler"
        filler.write_bytes(b"\0" * (1024 * 1024 - 3 * 60 * 1024))
        out = str(disk / "demos.hdf5")
        with pytest.raises(OSError, match="No space left on device") as failure:
            write_demos(out, count=8)
        assert failure.value.filename and failure.value.filename.startswith(out)
        finished = DemoWriter(out, {}, resume=True)
        kept = finished.count
        finished.abandon()
        assert 1 <= kept < 8 and not os.path.exists(out)
        filler.unlink()
        write_demos(out, resume=True, count=8)
        assert file_contents(out) == file_contents(write_demos(str(tmp_path / "reference.hdf5"), count=8))
    finally:
        subprocess.run(["umount", str(disk)], capture_output=True)


def test_a_running_chain_holds_its_directory(tmp_path):
    from base_suites.runtime.locks import output_lock
    from elegant.chain_config import load_recipe
    from elegant.pipeline import run_chain

    out = tmp_path / "chain"
    with output_lock(out):
        with pytest.raises(UserInputError, match="chain: in use by another run"):
            run_chain(str(out), load_recipe("quickstart"), progress=False)
    assert not out.exists()


def test_a_journal_begun_on_another_simulator_stack_is_not_resumed(tmp_path):
    """The file records the stack it was made on; a journal begun under another MuJoCo release is refused in
    one line naming both, and its demos stay for a resume on that stack."""
    out = str(tmp_path / "demos.hdf5")
    writer = DemoWriter(out, {"env_args": {"env_name": "libero"}})
    writer.append(synthetic_demo(0), [["state", 12]])
    assert writer.attrs["stack"]["mujoco"] and writer.attrs["stack"]["robosuite"] == "1.4.0"
    writer.abandon()
    header = os.path.join(out + ".partial", "header.h5")
    with h5py.File(header, "r+") as h5:
        stack = json.loads(h5.attrs["stack"])
        h5.attrs["stack"] = json.dumps({**stack, "mujoco": "3.14.0"})
    with pytest.raises(UserInputError, match=r"demos.hdf5.partial: begun with mujoco '3.14.0' but this stack has '"):
        DemoWriter(out, {}, resume=True)
    assert sorted(os.listdir(out + ".partial")) == ["demo_0.h5", "header.h5"]
