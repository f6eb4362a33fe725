"""A policy served over openpi's websocket protocol, as a `ChunkedPolicy` (see `elegant.policies.protocol`).

The connection is openpi-client's own `WebsocketClientPolicy` (install with `pip install -e .[openpi]`
and `pip install --no-deps openpi-client==0.1.2`, see the README). Each decision sends the observation in
openpi's LIBERO keys (`observation/image`, `observation/wrist_image`, `observation/state`, `prompt`; the
env's `obs="vla"` mode makes them) and reads back `actions`, a chunk (H, 7) of which the first
`replan_steps` are executed, as openpi's LIBERO client does.

A server that announces this project's extension in its metadata (`elegant serve-policy`) also gets the
env's full `state`, episode starts (metadata and seed, so runs repeat), the observations inside a chunk
(so a history window stays complete), and requests for `n` sampled chunks at once; JITI's candidates then
come from the policy's own distribution. A plain openpi server is asked `n` times instead (its sampling
is stochastic). Every failure is one line naming the address: no server, a timeout, an error reply, a
reply without `actions`, or actions of the wrong shape or not finite.
"""

from __future__ import annotations

import json
import os
import warnings
from collections import deque
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import TimeoutError as ReplyTimeout
from typing import Any

import numpy as np

from base_suites.runtime.errors import UserInputError
from elegant.policies.protocol import ACTION_DIM, ACTION_HIGH, ACTION_LOW, ExecutesPlans, Observation, check_count

EXTENSION = "libero_elegant"  # the server metadata key of this project's protocol extension
OPENPI_REPLAN_STEPS = 5  # openpi's LIBERO client executes 5 actions of each chunk
API_KEY_ENV = "ELEGANT_POLICY_API_KEY"  # the key sent to a server that asks for one (openpi's Api-Key header)
VLA_KEYS = {"image": "observation/image", "wrist_image": "observation/wrist_image", "vla_state": "observation/state"}


def server_uri(address: str) -> str:
    """`openpi://host:port` as the websocket URI it names; ws:// and wss:// pass through."""
    return "ws://" + address.removeprefix("openpi://") if address.startswith("openpi://") else address


class OpenPIPolicy(ExecutesPlans):
    """The policy an openpi policy server at `address` serves (see the module docstring). `replan_steps`:
    actions executed per chunk (default: the server's chunk when it announces one, else 5); `timeout`:
    seconds to wait for a reply."""

    def __init__(self, address: str, *, replan_steps: int | None = None, timeout: float = 60.0) -> None:
        try:
            import websockets.exceptions
            from openpi_client.websocket_client_policy import WebsocketClientPolicy
        except ImportError:
            raise UserInputError(
                f"policy {address}: needs openpi-client: pip install -e .[openpi] && "
                "pip install --no-deps openpi-client==0.1.2"
            ) from None
        self.address, self.timeout = address, float(timeout)
        self._closed_errors = (websockets.exceptions.ConnectionClosed, OSError)
        try:
            with warnings.catch_warnings():  # websockets 14+ asks for a context manager that the client does not use
                warnings.simplefilter("ignore", DeprecationWarning)
                self._client = WebsocketClientPolicy(host=server_uri(address), api_key=os.environ.get(API_KEY_ENV))
        except (OSError, TimeoutError, websockets.exceptions.WebSocketException) as exc:
            raise UserInputError(f"policy {address}: no policy server answers ({_one_line(exc)})") from None
        metadata = self._client.get_server_metadata()
        extension = metadata.get(EXTENSION) if isinstance(metadata, dict) else None
        self.extension: dict[str, Any] = dict(extension) if isinstance(extension, dict) else {}
        served = self.extension.get("chunk")
        self.chunk = int(replan_steps or served or OPENPI_REPLAN_STEPS)
        if served is not None and self.chunk > int(served):
            raise UserInputError(f"policy {address}: --replan-steps {self.chunk} exceeds the served chunk of {served}")
        self.candidate_source = "server samples" if self.extension.get("samples") else "repeated calls"
        self._pool = ThreadPoolExecutor(max_workers=1)
        self._queue: deque[np.ndarray] = deque()
        self._metadata: Mapping[str, Any] = {}
        self._pending_reset: dict[str, Any] | None = None

    def reset(self, metadata: Mapping[str, Any] | None = None, *, seed: int | None = None) -> None:
        self._metadata = dict(metadata or {})
        self._queue.clear()
        self._pending_reset = {"metadata": json.dumps(self._metadata, default=str), "seed": seed}

    def plan(self, obs: Observation) -> np.ndarray:
        reply = self._request(obs, "plan")
        return self._chunks(reply, None)[0]

    def sample_plans(self, obs: Observation, n: int) -> np.ndarray:
        n = check_count(n)
        if self.extension.get("samples"):
            return self._chunks(self._request(obs, "samples", n), n)
        return np.stack([self._chunks(self._request(obs, "plan"), None)[0] for _ in range(n)])

    def sample(self, obs: Observation, n: int) -> np.ndarray:
        return self.sample_plans(obs, n)[:, 0]

    def observe(self, obs: Observation) -> None:
        """Show the server an observation inside a chunk (only one that keeps a history wants it)."""
        if self.extension.get("observes"):
            self._request(obs, "observe")

    def close(self) -> None:
        self._client._ws.close()  # openpi-client 0.1.2 has no close() of its own
        self._pool.shutdown(wait=False)

    def _request(self, obs: Observation, kind: str, n: int | None = None) -> Any:
        payload: dict[str, Any] = {key: np.asarray(obs[name]) for name, key in VLA_KEYS.items() if name in obs}
        payload["prompt"] = str(self._metadata.get("instruction", ""))
        if self.extension:
            if "state" in obs:
                payload[f"{EXTENSION}/state"] = np.asarray(obs["state"], dtype=np.float64)
            payload[f"{EXTENSION}/kind"] = kind
            if n is not None:
                payload[f"{EXTENSION}/n"] = int(n)
            if self._pending_reset is not None:
                payload[f"{EXTENSION}/reset"] = json.dumps(self._pending_reset)
        elif len(payload) < len(VLA_KEYS) + 1:
            raise UserInputError(
                f"policy {self.address}: an openpi server reads LIBERO's VLA observation; run with --obs vla"
            )
        reply = self._infer(payload)
        self._pending_reset = None
        return reply

    def _infer(self, payload: dict[str, Any]) -> Any:
        pending = self._pool.submit(self._client.infer, payload)
        try:
            return pending.result(timeout=self.timeout)
        except ReplyTimeout:
            self._client._ws.close()  # ends the waiting call
            raise UserInputError(f"policy {self.address}: no reply within {self.timeout:g} s") from None
        except RuntimeError as exc:  # openpi-client's way of passing on a server's error reply
            raise UserInputError(f"policy {self.address}: the server refused the request: {_one_line(exc)}") from None
        except self._closed_errors as exc:
            raise UserInputError(f"policy {self.address}: the connection failed ({_one_line(exc)})") from None

    def _chunks(self, reply: dict[str, Any], n: int | None) -> np.ndarray:
        """The reply's actions as (n or 1, replan_steps, 7), checked and clipped to the action bounds."""
        if not isinstance(reply, dict) or "actions" not in reply:
            keys = sorted(reply) if isinstance(reply, dict) else type(reply).__name__
            raise UserInputError(f"policy {self.address}: the reply has no 'actions' (got {keys})")
        actions = np.asarray(reply["actions"], dtype=np.float64)
        if n is None and actions.ndim == 2:
            actions = actions[None]
        expected = f"({'' if n is None else f'{n}, '}H >= {self.chunk}, {ACTION_DIM})"
        if actions.ndim != 3 or actions.shape[0] != (n or 1) or actions.shape[1] < self.chunk:
            raise UserInputError(f"policy {self.address}: actions of shape {actions.shape}; expected {expected}")
        if actions.shape[2] != ACTION_DIM:
            raise UserInputError(f"policy {self.address}: actions of shape {actions.shape}; expected {expected}")
        if not np.isfinite(actions).all():
            raise UserInputError(f"policy {self.address}: the actions hold NaN or infinity")
        return np.clip(actions[:, : self.chunk], ACTION_LOW, ACTION_HIGH)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__
