"""Episodes replayed exactly from their records and written as videos (`elegant report --videos K`), on the real
simulator at tiny sizes."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from annotations.collect import collect_demos
from base_suites.runtime.errors import UserInputError
from elegant.cli import main
from elegant.evaluation.runner import evaluate
from elegant.policies.bc_train import train_policy
from elegant.reporting.replay import recorded_actions, replay_episode, replay_record, write_video
from elegant.reporting.report import compare_runs
from elegant.reporting.videos import choose_clips

pytestmark = pytest.mark.sim
SUITE = "libero_object"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A base and a random-mode run of one tiny policy on the same starts."""
    root = tmp_path_factory.mktemp("videos")
    demos = str(root / "demos.hdf5")
    collect_demos(SUITE, [0], demos, episodes=1, quality="clean", seed=0, progress=False)
    policy = str(root / "policy")
    train_policy([demos], policy, epochs=1, chunk=1, progress=False)
    settings = {"episodes": 2, "max_steps": 12, "seed": 0, "progress": False}
    base = evaluate(SUITE, [0], policy, None, out=root / "base", mode="base", **settings)
    evaluate(SUITE, [0], policy, None, out=root / "random", mode="random", random_rate=1.0, **settings)
    assert base["episodes"] == 2
    return root


def records(run_dir) -> list[dict]:
    return [json.loads(line) for line in (run_dir / "episodes.jsonl").read_text().splitlines()]


def made_elegant_copy(runs, tmp_path):
    """A copy of the random run whose first episode is marked a success and elegant: beside the base run
    that pair is "made elegant" and gets a clip. Returns the copy and its records."""
    edited = tmp_path / "random"
    shutil.copytree(runs / "random", edited)
    lines = records(edited)
    lines[0]["elegant"] = lines[0]["success"] = True
    (edited / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
    return edited, lines


def test_a_replayed_episode_ends_in_the_recorded_state(runs):
    record = records(runs / "random")[1]
    replay = replay_episode(runs / "random", record, size=64)
    assert len(replay.frames) == record["steps"] + 1 and replay.frames[0].shape == (64, 64, 3)
    trace = json.loads((runs / "random" / record["trace"]).read_text())
    assert recorded_actions(trace["replay"]).shape == (record["steps"], 7)
    # The check has teeth: another action sequence ends elsewhere and is refused.
    actions = recorded_actions(trace["replay"]).copy()
    actions[0, 0] = -actions[0, 0] if actions[0, 0] else 0.5
    tampered = runs / "tampered"
    shutil.copytree(runs / "random", tampered)
    trace["replay"] = {
        **replay_record(actions, np.zeros(1)),
        "final_state_sha256": trace["replay"]["final_state_sha256"],
    }
    (tampered / record["trace"]).write_text(json.dumps(trace))
    with pytest.raises(RuntimeError, match="another simulator state"):
        replay_episode(tampered, record, size=64)
    del trace["replay"]
    (tampered / record["trace"]).write_text(json.dumps(trace))
    with pytest.raises(UserInputError, match="recorded before episodes kept their actions"):
        replay_episode(tampered, record, size=64)


def test_clips_are_chosen_by_group_from_paired_starts():
    def rec(episode, success, elegant):
        return {"task": "t/0", "episode": episode, "init_index": episode, "seed": 7 + episode,
                "success": success, "elegant": elegant}  # fmt: skip

    first = [rec(0, True, False), rec(1, True, True), rec(2, False, False), rec(3, True, False)]
    later = [rec(0, True, True), rec(1, True, False), rec(2, False, False), rec(3, True, True)]
    clips = choose_clips([first, later], k=1)
    assert [(c["group"], c["runs"], c["records"][-1]["episode"]) for c in clips] == [
        ("made_elegant", [0, 1], 0),  # k = 1: episode 3, also made elegant, is left out
        ("spoiled", [0, 1], 1),
        ("inelegant_success", [0], 0),
        ("inelegant_success", [1], 1),
    ]
    assert len(choose_clips([first, later], k=5)) == 6


def test_report_writes_side_by_side_clips(runs, tmp_path):
    import imageio.v2 as imageio

    edited, lines = made_elegant_copy(runs, tmp_path)
    result = compare_runs([runs / "base", edited], tmp_path / "report", videos=1)
    made = [c for c in result["clips"] if c["group"] == "made_elegant"]
    assert len(made) == 1 and made[0]["episode"] == lines[0]["episode"]
    video = imageio.mimread(tmp_path / "report" / made[0]["path"], memtest=False)
    steps = max(r["steps"] for r in (records(runs / "base")[0], lines[0]))
    assert len(video) == steps + 1 and video[0].shape[1] == 2 * video[0].shape[0]  # two runs side by side
    assert made[0]["path"] in (tmp_path / "report" / "comparison.md").read_text()


def test_videos_need_an_output_directory(runs, capsys):
    assert main(["report", str(runs / "base"), "--videos", "2"]) == 2
    assert "give --out DIR" in capsys.readouterr().err


def test_video_is_written_whole(tmp_path):
    import imageio.v2 as imageio

    frames = [np.full((32, 48, 3), i * 20, dtype=np.uint8) for i in range(6)]
    path = write_video(tmp_path / "clip.mp4", frames)
    assert len(imageio.mimread(path, memtest=False)) == 6
    assert [p.name for p in tmp_path.iterdir()] == ["clip.mp4"]


def open_in_chromium(page, screenshot) -> dict:
    """Open `page` in Debian's headless chromium over the DevTools protocol, wait until it has loaded and
    its videos have their metadata (or failed), save a screenshot, and return what each <img> and <video>
    loaded: {"images": [[src, naturalWidth]], "videos": [[src, readyState, error]]}."""
    import base64
    import socket
    import subprocess
    import time
    import urllib.request

    from websockets.sync.client import connect

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    profile = screenshot.parent / "chromium-profile"
    browser = subprocess.Popen(
        [shutil.which("chromium"), "--headless=new", "--no-sandbox", "--disable-gpu", "--mute-audio",
         f"--remote-debugging-port={port}", f"--user-data-dir={profile}", "about:blank"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        for _ in range(100):
            try:
                targets = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=1).read())
                break
            except OSError:
                time.sleep(0.2)
        target = next(t for t in targets if t["type"] == "page")
        with connect(target["webSocketDebuggerUrl"], max_size=None) as ws:
            ids = iter(range(1, 100))

            def call(method, **params):
                n = next(ids)
                ws.send(json.dumps({"id": n, "method": method, "params": params}))
                while True:
                    message = json.loads(ws.recv(timeout=60))
                    if message.get("id") == n:
                        return message["result"]

            call("Page.enable")
            call("Page.navigate", url=page.resolve().as_uri())
            while json.loads(ws.recv(timeout=60)).get("method") != "Page.loadEventFired":
                pass
            script = """new Promise(done => {
                const videos = Array.from(document.querySelectorAll('video'));
                const ready = () => videos.every(v => v.readyState >= 1 || v.error);
                const report = () => done({
                    images: Array.from(document.images).map(i => [i.getAttribute('src'), i.naturalWidth]),
                    videos: videos.map(v => [v.getAttribute('src'), v.readyState, v.error ? v.error.code : null])});
                let waited = 0;
                const poll = () => (ready() || waited > 20000) ? report() : (waited += 100, setTimeout(poll, 100));
                poll();
            })"""
            loaded = call("Runtime.evaluate", expression=script, awaitPromise=True, returnByValue=True)
            shot = call("Page.captureScreenshot", format="png")
            screenshot.write_bytes(base64.b64decode(shot["data"]))
            return loaded["result"]["value"]
    finally:
        browser.kill()
        browser.wait()


@pytest.mark.skipif(shutil.which("chromium") is None, reason="needs Debian's chromium (scripts/setup.sh installs it)")
def test_the_html_page_loads_every_plot_and_video_in_a_browser(runs, tmp_path):
    edited, _ = made_elegant_copy(runs, tmp_path)
    compare_runs([runs / "base", edited], tmp_path / "report", videos=1)
    page = tmp_path / "report" / "comparison.html"
    loaded = open_in_chromium(page, tmp_path / "page.png")
    assert [src for src, _ in loaded["images"]] == ["comparison.png"]
    assert all(width > 0 for _, width in loaded["images"]), loaded
    assert [src for src, *_ in loaded["videos"]] == ["videos/made_elegant/libero_object_0_ep0_base_vs_random.mp4"]
    assert all(state >= 1 and error is None for _, state, error in loaded["videos"]), loaded
    screenshot = (tmp_path / "page.png").read_bytes()
    assert screenshot.startswith(b"\x89PNG") and len(screenshot) > 10_000
