"""Policies that are not ours: `elegant serve-policy` against the real openpi-client, a plain openpi-style
server, and `module:factory` entry points, through the policy spec every command takes."""

from __future__ import annotations

import json
import os
import re
import threading
import time

import numpy as np
import pytest

from base_suites import UserInputError, make_env
from elegant.evaluation.runner import evaluate
from elegant.policies import load_policy
from elegant.policies.remote import API_KEY_ENV, OpenPIPolicy
from elegant.policies.specs import open_policy

pytestmark = pytest.mark.sim
pytest.importorskip("openpi_client", reason="needs openpi-client (scripts/setup.sh installs it)")


@pytest.fixture(scope="module")
def policy_dir(tmp_path_factory):
    """A small per-step BC policy of libero_object/0 trained on two expert demos."""
    from annotations.collect import collect_demos
    from elegant.policies import train_policy

    root = tmp_path_factory.mktemp("served")
    demos = collect_demos("libero_object", [0], str(root / "demos.hdf5"), episodes=2, seed=0, progress=False)
    train_policy([demos["out"]], str(root / "policy"), epochs=2, hidden=(32,), chunk=1, progress=False)
    return str(root / "policy")


@pytest.fixture(scope="module")
def critic_dir(policy_dir):
    """A few steps of a critic on the same demos' annotation (for the JITI modes from the CLI)."""
    from annotations import annotate_file
    from critics import train_critic

    root = os.path.dirname(policy_dir)
    annotate_file(os.path.join(root, "demos.hdf5"), os.path.join(root, "annotated.hdf5"), progress=False)
    train_critic([os.path.join(root, "annotated.hdf5")], os.path.join(root, "critic"), steps=5, chunk=1, progress=False)
    return os.path.join(root, "critic")


class Server:
    """`serve_policy` in a background thread, stopped at exit."""

    def __init__(self, serve, **kwargs):
        self.address = None
        ready = threading.Event()

        def note(address):
            self.address = address
            ready.set()

        self.thread = threading.Thread(target=serve, kwargs={**kwargs, "ready": note}, daemon=True)
        self.thread.start()
        assert ready.wait(30), "the server did not start"


@pytest.fixture(scope="module")
def served(policy_dir):
    from elegant.policies.server import serve_policy

    return Server(serve_policy, path=policy_dir, port=0).address


def episode_observations(obs_mode="lowdim", steps=6):
    env = make_env("libero_object", 0, seed=0, obs=obs_mode, camera_size=32)
    try:
        obs, _ = env.reset(seed=1, options={"init_state": 2})
        out, rng = [obs], np.random.default_rng(0)
        for _ in range(steps - 1):
            obs = env.step(rng.uniform(-0.5, 0.5, 7))[0]
            out.append(obs)
        return out, env.metadata
    finally:
        env.close()


def test_a_served_policy_plans_and_samples_as_the_same_policy_in_process(policy_dir, served):
    observations, metadata = episode_observations()
    remote, local = OpenPIPolicy(served), load_policy(policy_dir)
    assert remote.chunk == local.chunk and remote.candidate_source == "server samples"
    for policy in (remote, local):
        policy.reset(metadata, seed=7)
    for obs in observations:
        np.testing.assert_array_equal(remote.plan(obs), local.plan(obs))
        np.testing.assert_array_equal(remote.sample_plans(obs, 4), local.sample_plans(obs, 4))
    remote.close()


def test_jiti_over_a_served_policy_with_vla_images_repeats_the_in_process_run(policy_dir, served, tmp_path):
    from test_evaluation import ReachCritic

    settings = {"mode": "always", "episodes": 2, "seed": 0, "max_steps": 6, "obs": "vla", "progress": False}
    runs = {
        name: evaluate("libero_object", [0], policy, ReachCritic(), out=tmp_path / name, **settings)
        for name, policy in (("served", served), ("local", policy_dir))
    }
    assert runs["served"]["interventions_per_episode"] > 0
    for key in ("success_rate", "esr", "interventions_per_episode", "overrides_per_episode"):
        assert runs["served"][key] == runs["local"][key]
    assert runs["served"]["config"]["policy"] == served


def test_the_server_refuses_bad_messages_and_outlives_its_clients(served):
    from openpi_client import msgpack_numpy
    from websockets.sync.client import connect

    with connect(served, compression=None, max_size=None) as ws:
        assert "chunk" in msgpack_numpy.unpackb(ws.recv())["libero_elegant"]
        ws.send(b"\xc1 not msgpack")
        assert "malformed msgpack" in ws.recv()
        ws.send(msgpack_numpy.packb({"libero_elegant/state": np.array([b"x"], dtype=object).astype("S1")}))
        assert "not accepted" in ws.recv()  # only numeric arrays are decoded
        ws.send(msgpack_numpy.packb({"prompt": "no state"}))
        assert "reads the env state" in ws.recv()
    # a client gone mid-episode (the block above closed without an episode's end) left the server serving
    observations, metadata = episode_observations(steps=1)
    remote = OpenPIPolicy(served)
    remote.reset(metadata, seed=0)
    assert remote.plan(observations[0]).shape == (1, 7)


def test_an_api_key_is_required_when_the_server_has_one(policy_dir, monkeypatch):
    from elegant.policies.server import serve_policy

    address = Server(serve_policy, path=policy_dir, port=0, api_key="s3cret").address
    monkeypatch.delenv(API_KEY_ENV, raising=False)
    with pytest.raises(UserInputError, match=f"policy {address}: no policy server answers .*401"):
        OpenPIPolicy(address)
    monkeypatch.setenv(API_KEY_ENV, "wrong")
    with pytest.raises(UserInputError, match="401"):
        OpenPIPolicy(address)
    monkeypatch.setenv(API_KEY_ENV, "s3cret")
    assert OpenPIPolicy(address).chunk == 1


def plain_openpi_server(reply):
    """A server speaking openpi's protocol only (as openpi's own servers do): `reply(request)` answers."""
    from openpi_client import msgpack_numpy
    from websockets.sync.server import serve

    def handler(ws):
        ws.send(msgpack_numpy.packb({}))
        for message in ws:
            answer = reply(msgpack_numpy.unpackb(message))
            ws.send(answer if isinstance(answer, str) else msgpack_numpy.packb(answer))

    server = serve(handler, "127.0.0.1", 0, compression=None)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, f"ws://127.0.0.1:{server.socket.getsockname()[1]}"


def test_a_plain_openpi_server_gets_vla_observations_and_its_chunks_are_replanned():
    requests = []
    rng = np.random.default_rng(0)

    def reply(request):
        requests.append(request)
        return {"actions": rng.uniform(-0.5, 0.5, size=(10, 7))}

    server, address = plain_openpi_server(reply)
    observations, metadata = episode_observations("vla", steps=7)
    policy = open_policy(address.replace("ws://", "openpi://"))
    assert policy.chunk == 5 and policy.candidate_source == "repeated calls"
    policy.reset(metadata, seed=0)
    actions = [policy(obs) for obs in observations]
    assert len(requests) == 2  # a decision every 5 steps
    first = requests[0]
    assert set(first) == {"observation/image", "observation/wrist_image", "observation/state", "prompt"}
    assert first["observation/image"].shape == (32, 32, 3) and first["prompt"] == metadata["instruction"]
    np.testing.assert_array_equal(first["observation/state"], observations[0]["vla_state"])
    assert len(actions) == 7 and np.all(np.abs(actions) <= 1)
    assert policy.sample_plans(observations[-1], 3).shape == (3, 5, 7) and len(requests) == 5  # one call each
    lowdim, _ = episode_observations(steps=1)
    with pytest.raises(UserInputError, match="reads LIBERO's VLA observation; run with --obs vla"):
        policy.plan(lowdim[0])
    server.shutdown()


@pytest.mark.parametrize(
    "reply, message",
    [
        ({"action": np.zeros((10, 7))}, "the reply has no 'actions'"),
        ({"actions": np.zeros((10, 6))}, r"actions of shape \(1, 10, 6\)"),
        ({"actions": np.zeros((3, 7))}, r"actions of shape \(1, 3, 7\); expected \(H >= 5, 7\)"),
        ({"actions": np.full((10, 7), np.nan)}, "the actions hold NaN or infinity"),
        ("KeyError: 'observation/image'", "the server refused the request: Error in inference server"),
    ],
)
def test_a_bad_reply_is_refused_in_one_line_naming_the_server(reply, message):
    server, address = plain_openpi_server(lambda request: reply)
    observations, metadata = episode_observations("vla", steps=1)
    policy = OpenPIPolicy(address)
    policy.reset(metadata)
    with pytest.raises(UserInputError, match=f"policy {address}: {message}"):
        policy.plan(observations[0])
    server.shutdown()


def test_an_unreachable_or_silent_server_is_refused_in_one_line():
    with pytest.raises(UserInputError, match="policy ws://127.0.0.1:9: no policy server answers"):
        OpenPIPolicy("ws://127.0.0.1:9")
    server, address = plain_openpi_server(lambda request: time.sleep(3) or {"actions": np.zeros((10, 7))})
    observations, metadata = episode_observations("vla", steps=1)
    policy = OpenPIPolicy(address, timeout=0.5)
    policy.reset(metadata)
    with pytest.raises(UserInputError, match=f"policy {address}: no reply within 0.5 s"):
        policy.plan(observations[0])
    server.shutdown()


def test_an_entry_point_policy_runs_and_bad_ones_are_refused_in_one_line(tmp_path):
    policy = open_policy('policy_entry_points:make_policy:{"gain": 0.5}')
    assert policy({})[2] == -0.5
    summary = evaluate(
        "libero_object", [0], "policy_entry_points:make_policy", mode="base", episodes=1, max_steps=4,
        out=tmp_path / "run", progress=False,
    )  # fmt: skip
    assert summary["config"]["policy"] == "policy_entry_points:make_policy" and summary["steps_per_episode"] == 4
    for spec, message in [
        ("no_such_module:make", "cannot import no_such_module"),
        ("policy_entry_points:missing", "has no callable missing"),
        ("policy_entry_points:make_nothing", "returned a int; expected a policy"),
        ("policy_entry_points:make_broken", r"make_broken\(\*\*kwargs\) failed"),
        ("policy_entry_points:make_policy:{not json}", "are not JSON"),
    ]:
        with pytest.raises(UserInputError, match=f"policy {re.escape(spec)}: .*{message}"):
            open_policy(spec)


def test_serve_policy_refuses_bad_settings_before_listening(tmp_path, capsys):
    from elegant.cli import main

    assert main(["serve-policy", str(tmp_path / "missing"), "--port", "0"]) == 2
    assert "no such policy directory" in capsys.readouterr().err
    assert main(["serve-policy", str(tmp_path), "--port", "70000"]) == 2
    assert "expected 0..65535" in capsys.readouterr().err
    (tmp_path / "key").write_text("\n")
    assert main(["serve-policy", str(tmp_path), "--api-key-file", str(tmp_path / "key")]) == 2
    assert "API key file is empty" in capsys.readouterr().err


def test_clients_are_served_side_by_side_and_an_oversized_message_closes_only_its_connection(policy_dir, monkeypatch):
    from openpi_client import msgpack_numpy
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    from elegant.policies import server

    monkeypatch.setattr(server, "MAX_MESSAGE_BYTES", 4096)
    address = Server(server.serve_policy, path=policy_dir, port=0).address
    observations, metadata = episode_observations(steps=4)
    clients = [OpenPIPolicy(address) for _ in range(2)]
    for seed, client in enumerate(clients):
        client.reset(metadata, seed=seed)
    local = load_policy(policy_dir)
    plans = {}

    def run(i):
        plans[i] = [clients[i].sample_plans(obs, 3) for obs in observations]

    threads = [threading.Thread(target=run, args=(i,)) for i in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    for seed in range(2):  # each connection kept its own generator: as two policies in-process
        local.reset(metadata, seed=seed)
        for obs, plan in zip(observations, plans[seed]):
            np.testing.assert_array_equal(plan, local.sample_plans(obs, 3))
    with connect(address, compression=None, max_size=None) as ws:
        ws.recv()
        ws.send(msgpack_numpy.packb({"blob": np.zeros(10_000, dtype=np.uint8)}))
        with pytest.raises(ConnectionClosed):
            ws.recv()
    clients[0].reset(metadata, seed=0)
    assert clients[0].plan(observations[0]).shape == (1, 7)  # the server and its other clients carried on


def test_a_lerobot_style_entry_point_sees_both_cameras_under_eval_from_the_cli(tmp_path, capsys):
    import policy_entry_points

    from elegant.cli import main

    code = main(
        ["eval", "--suite", "libero_object", "--tasks", "0", "--policy", "policy_entry_points:make_lerobot_style",
         "--mode", "base", "--episodes", "1", "--max-steps", "3", "--obs", "vla", "--out", str(tmp_path / "run")]
    )  # fmt: skip
    assert code == 0, capsys.readouterr().err
    seen = policy_entry_points.LAST_LEROBOT[-1].batches[0]
    assert seen["observation.images.image"] == seen["observation.images.image2"] == (1, 3, 256, 256)
    assert seen["observation.state"] == (1, 8) and seen["task"] == ["pick the alphabet soup and place it in the basket"]


def test_a_served_policys_own_rollouts_are_recorded_with_vla_observations_and_annotated(served, tmp_path):
    from annotations import annotate_file
    from elegant.evaluation.rollouts import collect_rollouts

    out = str(tmp_path / "own.hdf5")
    summary = collect_rollouts("libero_object", [0], served, out, episodes=1, max_steps=4, obs="vla", progress=False)
    assert summary["episodes"] == 1
    labelled = annotate_file(out, str(tmp_path / "own_annotated.hdf5"), progress=False)
    assert labelled["demos"] == 1


def test_a_served_policy_runs_under_elegant_eval_from_the_cli_and_resumes(served, tmp_path, capsys):
    from elegant.cli import main

    args = ["eval", "--suite", "libero_object", "--tasks", "0", "--policy", served, "--mode", "base",
            "--max-steps", "3", "--obs", "vla", "--out", str(tmp_path / "run")]  # fmt: skip
    assert main([*args, "--episodes", "1"]) == 0, capsys.readouterr().err
    assert main([*args, "--episodes", "2", "--resume"]) == 0, capsys.readouterr().err
    records = (tmp_path / "run" / "episodes.jsonl").read_text().splitlines()
    assert (
        len(records) == 2 and '"candidate_source": "server samples"' in (tmp_path / "run" / "config.json").read_text()
    )


@pytest.mark.parametrize("mode", ["always", "jiti"])
@pytest.mark.parametrize("kind", ["served", "entry point", "lerobot-style"])
def test_every_kind_of_policy_runs_under_the_jiti_modes_from_the_cli_with_images(
    kind, mode, served, critic_dir, tmp_path, capsys
):
    from elegant.cli import main

    policy = {"served": served, "entry point": "policy_entry_points:make_policy",
              "lerobot-style": "policy_entry_points:make_lerobot_style"}[kind]  # fmt: skip
    code = main(
        ["eval", "--suite", "libero_object", "--tasks", "0", "--policy", policy, "--critic", critic_dir,
         "--mode", mode, "--episodes", "1", "--max-steps", "3", "--obs", "vla",
         *(["--window", "1"] if mode == "jiti" else []), "--out", str(tmp_path / "run")]
    )  # fmt: skip
    assert code == 0, capsys.readouterr().err
    config = (tmp_path / "run" / "config.json").read_text()
    assert f'"mode": "{mode}"' in config and '"obs": "vla"' in config
    if mode == "always":  # the critic re-ranked the policy's candidates at every decision
        assert json.loads(capsys.readouterr().out)["interventions_per_episode"] > 0
