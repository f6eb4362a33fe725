"""`elegant serve-policy`: a `train-policy` policy served over openpi's websocket protocol.

The protocol is openpi's: on connect the server sends its metadata (msgpack), then answers each msgpack
observation with `{"actions": chunk}`; an error is a text reply, which openpi-client raises. The metadata
announces this project's extension (`elegant.policies.remote`), with which the client also sends the
full state, episode starts, the observations inside a chunk, and requests for `n` sampled chunks, so a
served policy acts exactly as the same policy in-process.

Each connection gets its own policy (its own history and generators), so several clients (one per eval
worker) are served at once, each in a thread, and a client that disconnects mid-episode takes nothing
with it. What arrives is decoded by msgpack with numeric arrays only (never pickle; object, void and
complex dtypes are refused); a malformed or refused request gets an error reply and the connection stays
open; a message over `max_message_bytes` closes that connection (websockets' limit) and the server
stays up. With `api_key`, a connection must send `Authorization: Api-Key <key>` (what openpi-client
sends) or is refused before the handshake completes.
"""

from __future__ import annotations

import hmac
import json
import os
from collections.abc import Callable
from http import HTTPStatus
from typing import Any

import numpy as np

from base_suites.runtime.errors import UserInputError
from elegant.policies.protocol import DEFAULT_POLICY_ACT
from elegant.policies.remote import EXTENSION

MAX_MESSAGE_BYTES = 16 * 2**20  # two 256 px cameras and a state take under 0.5 MiB
_NUMERIC_KINDS = "biuf"  # bool, signed and unsigned integers, floats


def serve_policy(
    path: str,
    *,
    host: str = "127.0.0.1",
    port: int = 8000,
    act: str = DEFAULT_POLICY_ACT,
    api_key: str | None = None,
    ready: Callable[[str], None] | None = None,
) -> None:
    """Serve the policy directory `path` (acting as `act` says) until interrupted (Ctrl-C) or the server is
    shut down; `ready(address)` is called once it listens. Binds to `host` (loopback unless told)."""
    from websockets.sync.server import serve

    from elegant.policies.bc_policy import load_policy

    probe = load_policy(path, act=act)  # refuses a bad directory before anything listens
    metadata = {
        EXTENSION: {
            "format": 1,
            "policy": os.path.abspath(path),
            "act": act,
            "chunk": probe.chunk,
            "samples": True,
            "observes": True,
        }
    }

    def handler(connection: Any) -> None:
        _serve_connection(connection, load_policy(path, act=act), metadata)

    try:
        server = serve(
            handler,
            host,
            int(port),
            max_size=MAX_MESSAGE_BYTES,
            compression=None,
            process_request=None if api_key is None else _require_key(api_key),
        )
    except OSError as exc:
        raise UserInputError(f"serve-policy: cannot listen on {host}:{port} ({exc.strerror or exc})") from None
    with server:
        bound_host, bound_port = server.socket.getsockname()[:2]
        if ready is not None:
            ready(f"ws://{bound_host}:{bound_port}")
        try:
            server.serve_forever()
        except KeyboardInterrupt:
            pass


def _require_key(api_key: str) -> Callable[[Any, Any], Any]:
    expected = f"Api-Key {api_key}"

    def check(connection: Any, request: Any) -> Any:
        given = request.headers.get("Authorization", "")
        if not hmac.compare_digest(given.encode(), expected.encode()):
            return connection.respond(HTTPStatus.UNAUTHORIZED, "a valid Api-Key is required\n")
        return None

    return check


def _serve_connection(connection: Any, policy: Any, metadata: dict[str, Any]) -> None:
    from openpi_client import msgpack_numpy
    from websockets.exceptions import ConnectionClosed

    try:
        connection.send(msgpack_numpy.packb(metadata))
        for message in connection:
            try:
                reply = _answer(policy, decode(message))
            except (UserInputError, ValueError, TypeError, KeyError) as exc:
                connection.send(f"{type(exc).__name__}: {exc}")
                continue
            connection.send(msgpack_numpy.packb(reply))
    except ConnectionClosed:
        pass  # a client that went away mid-episode: its policy goes with this thread


def decode(message: bytes | str) -> dict[str, Any]:
    """A request as msgpack with numeric numpy arrays (openpi-client's encoding), decoded without pickle."""
    import msgpack

    if isinstance(message, str):
        raise ValueError("expected a binary msgpack message, got text")
    try:
        request = msgpack.unpackb(message, object_hook=_numeric_array, strict_map_key=False)
    except (msgpack.UnpackException, ValueError) as exc:
        raise ValueError(f"malformed msgpack message ({exc})") from None
    if not isinstance(request, dict):
        raise ValueError(f"expected a map of observation entries, got {type(request).__name__}")
    return request


def _numeric_array(obj: dict) -> Any:
    if b"__ndarray__" in obj or b"__npgeneric__" in obj:
        dtype = np.dtype(obj[b"dtype"])
        if dtype.kind not in _NUMERIC_KINDS:
            raise ValueError(f"arrays of dtype {dtype} are not accepted")
        if b"__npgeneric__" in obj:
            return dtype.type(obj[b"data"])
        shape = tuple(int(s) for s in obj[b"shape"])
        if any(s < 0 for s in shape) or int(np.prod(shape)) * dtype.itemsize != len(obj[b"data"]):
            raise ValueError(f"array data does not match shape {shape} of {dtype}")
        return np.frombuffer(obj[b"data"], dtype=dtype).reshape(shape)
    return obj


def _answer(policy: Any, request: dict[str, Any]) -> dict[str, Any]:
    reset = request.get(f"{EXTENSION}/reset")
    if reset is not None:
        start = json.loads(reset)
        policy.reset(json.loads(start["metadata"]) or None, seed=start.get("seed"))
    if f"{EXTENSION}/state" not in request:
        raise KeyError(f"this server's policy reads the env state: send {EXTENSION}/state (elegant's client does)")
    obs = {"state": np.asarray(request[f"{EXTENSION}/state"], dtype=np.float64)}
    kind = request.get(f"{EXTENSION}/kind", "plan")
    if kind == "plan":
        return {"actions": policy.plan(obs)}
    if kind == "samples":
        return {"actions": policy.sample_plans(obs, int(request[f"{EXTENSION}/n"]))}
    if kind == "observe":
        policy.observe(obs)
        return {}
    raise ValueError(f"unknown request kind {kind!r}; expected plan, samples or observe")
