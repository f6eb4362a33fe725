"""The trained BC policy on disk: `model.pt` (a plain state_dict) and `config.json` (everything else).

config.json holds the network shape (with `chunk`, the number of actions each decision predicts), the input
definition (task encoder with every task's state layout, per-task normalisation, history length), training
facts and library versions, plus the SHA-256 of model.pt so that a pair written by different runs (an
interrupted overwrite) is refused instead of producing nonsense actions. Both files are written atomically.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from typing import Any

import torch

from base_suites.runtime.errors import UserInputError
from base_suites.runtime.io import atomic_write, library_versions, read_artifact_config
from base_suites.runtime.training import torch_bytes
from base_suites.stack import cpu_record
from elegant.policies.bc_features import BCFeatures
from elegant.policies.bc_model import BCNet
from elegant.policies.protocol import ACTION_DIM

ARTIFACT_FORMAT = "libero-elegant-bc/1"
MODEL_FILE = "model.pt"
CONFIG_FILE = "config.json"


def write_artifact(out: str, net: BCNet, features: BCFeatures, model: dict[str, Any], training: dict[str, Any]) -> None:
    """Publish the final policy in `out` (model.pt first; config.json, which vouches for it, last). The
    weights are saved from the CPU, so a policy trained on a GPU loads anywhere."""
    payload = torch_bytes({k: v.detach().cpu() for k, v in net.state_dict().items()})
    atomic_write(os.path.join(out, MODEL_FILE), payload)
    config = {
        "format": ARTIFACT_FORMAT,
        "model": model,
        "features": features.to_dict(),
        "training": training,
        "versions": library_versions(),
        "machine": cpu_record(),  # trained weights depend on the CPU's float kernels
        "model_sha256": hashlib.sha256(payload).hexdigest(),
    }
    atomic_write(os.path.join(out, CONFIG_FILE), json.dumps(config, indent=1).encode())


def read_artifact(path: str) -> tuple[BCNet, BCFeatures, dict[str, Any]]:
    """Load a policy directory, refusing a missing, foreign, corrupt or inconsistent one in one line."""
    config = read_artifact_config(
        path,
        kind="policy",
        config_file=CONFIG_FILE,
        weights_file=MODEL_FILE,
        fmt=ARTIFACT_FORMAT,
        hint="the output of `elegant train-policy`",
    )
    model_path, config_path = os.path.join(path, MODEL_FILE), os.path.join(path, CONFIG_FILE)
    with open(model_path, "rb") as fh:
        payload = fh.read()
    if hashlib.sha256(payload).hexdigest() != config.get("model_sha256"):
        raise UserInputError(
            f"{model_path}: does not match config.json's model_sha256 (corrupt or from another run); retrain"
        )
    try:
        features = BCFeatures.from_dict(config["features"])
        spec = config["model"]
        spec.setdefault("chunk", 1)  # policies written before action chunking decide one action at a time
        spec.setdefault("task_dim", 0)  # ... and before FiLM task conditioning read the task at the input only
        net = BCNet(
            spec["input_dim"],
            hidden=spec["hidden"],
            action_dim=spec["action_dim"],
            modes=spec["modes"],
            min_std=spec["min_std"],
            task_dim=spec["task_dim"],
        )
        net.load_state_dict(torch.load(io.BytesIO(payload), map_location="cpu", weights_only=True))
    except KeyError as exc:
        raise UserInputError(f"{config_path}: missing field {exc.args[0]!r}") from None
    except (RuntimeError, TypeError, ValueError) as exc:
        raise UserInputError(
            f"{model_path}: cannot be loaded into the network config.json describes ({str(exc).splitlines()[0]})"
        ) from None
    if features.input_dim != spec["input_dim"]:
        raise UserInputError(
            f"{config_path}: model.input_dim {spec['input_dim']} disagrees with the features ({features.input_dim})"
        )
    if spec["action_dim"] != ACTION_DIM * spec["chunk"]:
        raise UserInputError(
            f"{config_path}: model.action_dim {spec['action_dim']} is not {ACTION_DIM} x model.chunk {spec['chunk']}"
        )
    net.eval()
    return net, features, config
