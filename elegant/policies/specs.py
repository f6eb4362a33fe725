"""One way to name a policy on the command line, for every command that takes `--policy`.

A policy spec is one of
- a directory written by `elegant train-policy`;
- `module:factory` or `module:factory:{"json": "kwargs"}`: a Python entry point, imported and called
  (with the kwargs), returning a policy object (a callable obs -> action, a LeRobot-style policy, a
  TorchRL module, or a full `Policy`);
- `ws://host:port` or `openpi://host:port`: a policy served over openpi's websocket protocol (a real
  openpi server, or `elegant serve-policy`), reached with the `openpi-client` package.

Specs are plain strings, so worker processes each open their own policy (a server gets one connection
per worker). Every failure to open one is one line naming the spec and what was expected.
"""

from __future__ import annotations

import importlib
import json
import os
import re
from typing import Any

from base_suites.runtime.errors import UserInputError
from elegant.policies.protocol import DEFAULT_POLICY_ACT

SERVER_SCHEMES = ("ws://", "wss://", "openpi://")
_ENTRY_POINT = re.compile(r"^(?P<module>[A-Za-z_][\w.]*):(?P<factory>[A-Za-z_]\w*)(?::(?P<kwargs>\{.*\}))?$", re.S)


def is_server(spec: str) -> bool:
    return spec.startswith(SERVER_SCHEMES)


def is_entry_point(spec: str) -> bool:
    return not os.path.exists(spec) and _ENTRY_POINT.match(spec) is not None


def describe_policy(spec: Any) -> str | None:
    """How a run's config names its policy: a directory's absolute path, a server's address, an entry point
    as written, or the qualified type name of a policy object."""
    if spec is None:
        return None
    if isinstance(spec, (str, os.PathLike)):
        spec = os.fspath(spec)
        return spec if is_server(spec) or is_entry_point(spec) else os.path.abspath(spec)
    named = spec if hasattr(spec, "__qualname__") else type(spec)
    return f"{named.__module__}.{named.__qualname__}"


def open_policy(spec: Any, act: str = DEFAULT_POLICY_ACT, *, replan_steps: int | None = None) -> Any:
    """The policy a spec names (see the module docstring), or a policy object passed through. `act` (one
    of POLICY_ACTS) applies to a `train-policy` directory only: every other policy decides its own
    actions. `replan_steps`: actions executed per chunk of a served policy (default: the server's chunk,
    else openpi's LIBERO default of 5)."""
    if not isinstance(spec, (str, os.PathLike)):
        _only_default_act(act, type(spec).__name__)
        if replan_steps is not None:
            raise UserInputError("replan_steps applies to a policy server; a policy object plans its own chunks")
        if not callable(spec):
            raise UserInputError(
                f"policy: expected a policy spec or a callable obs -> action, got {type(spec).__name__}"
            )
        return spec
    spec = os.fspath(spec)
    if replan_steps is not None and not is_server(spec):
        raise UserInputError(f"--replan-steps applies to a policy server (ws://...); {spec} plans its own chunks")
    if is_server(spec):
        from elegant.policies.remote import OpenPIPolicy

        _only_default_act(act, "policy server")
        return OpenPIPolicy(spec, replan_steps=replan_steps)
    if is_entry_point(spec):
        _only_default_act(act, "entry-point policy")
        return _call_entry_point(spec)
    from elegant.policies.bc_policy import load_policy

    return load_policy(spec, act=act)


def _only_default_act(act: str, what: str) -> None:
    if act != DEFAULT_POLICY_ACT:
        raise UserInputError(f"policy act {act!r} applies to a BC policy directory; a {what} decides its own actions")


def _call_entry_point(spec: str) -> Any:
    match = _ENTRY_POINT.match(spec)
    module_name, factory_name, kwargs_text = match.group("module", "factory", "kwargs")
    try:
        kwargs = json.loads(kwargs_text) if kwargs_text else {}
    except json.JSONDecodeError as exc:
        raise UserInputError(f"policy {spec}: the kwargs after the factory are not JSON ({exc.msg})") from None
    if not isinstance(kwargs, dict):
        raise UserInputError(f"policy {spec}: the kwargs after the factory must be a JSON object")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise UserInputError(f"policy {spec}: cannot import {module_name} ({exc})") from None
    factory = getattr(module, factory_name, None)
    if not callable(factory):
        raise UserInputError(f"policy {spec}: {module_name} has no callable {factory_name}")
    try:
        policy = factory(**kwargs)
    except TypeError as exc:
        raise UserInputError(f"policy {spec}: {factory_name}(**kwargs) failed ({exc})") from None
    if not (callable(policy) or callable(getattr(policy, "select_action", None))):
        raise UserInputError(
            f"policy {spec}: {factory_name} returned a {type(policy).__name__}; expected a policy (a callable "
            "obs -> action, or an object with select_action(batch))"
        )
    return policy
