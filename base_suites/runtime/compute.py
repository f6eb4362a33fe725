"""Where torch computes: the device that trains and scores networks, and the CPU thread count
(docs/design.md, compute).

`ComputeConfig` is torch-free, so the CLI builds its options without loading torch; `use_compute` applies
it in the process that trains or scores and returns the torch device. It is not part of what determines an
experiment's numbers on one kind of device, and a GPU's numbers differ from the CPU's in rounding only;
runs record the kind of device they used (`device_kind`) and refuse to resume on another. The CPU
thread count is a run control: it changes speed, not the numbers (tests/test_compute.py).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

from base_suites.runtime.errors import UserInputError
from base_suites.runtime.settings import setting

if TYPE_CHECKING:
    import torch

_DEVICE = re.compile(r"auto|cpu|cuda(:\d+)?")


@dataclass(frozen=True)
class ComputeConfig:
    """Where networks train and score; each field is also an option of the commands that run torch."""

    device: str = setting(
        "auto", "where networks train and score: auto (a GPU when torch sees one), cpu, cuda or cuda:N"
    )
    threads: int = setting(
        1,
        "torch's CPU threads; one, since more (torch's default: one per core) collapse when another job "
        "shares the cores (benchmarks/thread_settings.py)",
    )

    def validate(self, command: str) -> None:
        """Refuse a malformed device or thread count in one line (before torch is loaded)."""
        if not isinstance(self.device, str) or not _DEVICE.fullmatch(self.device):
            raise UserInputError(f"{command}: device must be auto, cpu, cuda or cuda:N, got {self.device!r}")
        if not isinstance(self.threads, int) or self.threads < 1:
            raise UserInputError(f"{command}: threads must be a positive integer, got {self.threads!r}")


def resolve_device(spec: str, command: str) -> torch.device:
    """The torch device `spec` names; "auto" is the first GPU when torch sees one, else the CPU. A GPU
    that is not there is refused in one line."""
    import torch

    ComputeConfig(device=spec).validate(command)
    if spec == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    device = torch.device(spec)
    if device.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise UserInputError(
                f"{command}: device {spec!r} but torch {torch.__version__} sees no GPU; use --device cpu or auto"
            )
        if device.index is not None and device.index >= count:
            raise UserInputError(
                f"{command}: device {spec!r} but torch sees {count} GPU(s), cuda:0 to cuda:{count - 1}"
            )
    return device


def use_compute(config: ComputeConfig, command: str) -> torch.device:
    """Apply `config` to this process: torch's thread count, and on a GPU the deterministic algorithms
    torch offers (docs/design.md says what stays reproducible there). Returns the device to use."""
    import torch

    config.validate(command)
    device = resolve_device(config.device, command)
    if torch.get_num_threads() != config.threads:
        torch.set_num_threads(config.threads)
    if device.type == "cuda":
        # cuBLAS needs a fixed workspace for reproducible matmuls; set before the first cuBLAS call
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
        torch.use_deterministic_algorithms(True, warn_only=True)
        torch.backends.cudnn.benchmark = False
    return device


def device_kind(device: torch.device) -> str:
    """What a run records of its device: "cpu", or "cuda" with the GPU's name (rounding differs by model)."""
    import torch

    if device.type != "cuda":
        return "cpu"
    return f"cuda ({torch.cuda.get_device_name(device)})"


def refuse_other_device(path: str, recorded: str, device: torch.device) -> None:
    """Refuse to continue a run written on another kind of device: its rounding differs, so the run would
    not match an uninterrupted one."""
    now = device_kind(device)
    if recorded != now:
        wanted = "cpu" if recorded == "cpu" else "cuda"
        raise UserInputError(
            f"{path}: written on {recorded} but this run computes on {now}; resume it with --device {wanted} "
            "on the same kind of device (another one rounds differently), or start afresh with --overwrite"
        )
