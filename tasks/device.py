"""Where training and inference run: the device, the matmul precision, bf16 and torch.compile.

``Runtime`` is how a run is executed, not what it computes: none of its fields enters a
config hash or a checkpoint id, and a checkpoint written on a GPU loads on a CPU (weights are
saved from CPU copies). ``device``: ``auto`` (CUDA when there is a GPU, else the CPU),
``cpu``, ``cuda`` or ``cuda:N``; the ``WORLDLINE_DEVICE`` environment variable is the default.
``tf32``: whether float32 matrix products and convolutions may use TF32 on a GPU (PyTorch
leaves it on for cuDNN convolutions and off for matmuls; here it is one explicit choice, off
by default so a GPU run computes what a CPU run does to float32 rounding). ``precision``
``bf16`` runs the forward pass under bfloat16 autocast (CUDA only). ``compile`` wraps the
model in ``torch.compile(mode="reduce-overhead")`` (CUDA graphs).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from typing import Literal

import torch
from pydantic import BaseModel, ConfigDict, Field, field_validator

ENV = "WORLDLINE_DEVICE"


class DeviceError(RuntimeError):
    """One line: the device asked for and why it cannot be used."""


class Runtime(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    device: str = Field(default_factory=lambda: os.environ.get(ENV, "auto"),
                        description="auto | cpu | cuda | cuda:N (default: $WORLDLINE_DEVICE or auto)")
    precision: Literal["fp32", "bf16"] = "fp32"
    compile: bool = False
    tf32: bool = False

    @field_validator("device")
    @classmethod
    def _known(cls, value: str) -> str:
        value = value.strip().lower()
        if value not in ("auto", "cpu", "cuda") and not (value.startswith("cuda:") and value[5:].isdigit()):
            raise ValueError(f"device {value!r}: expected auto, cpu, cuda or cuda:N")
        return value

    def torch_device(self) -> torch.device:
        return resolve(self.device)


def resolve(device: str = "auto") -> torch.device:
    """The torch device for ``device``; DeviceError when CUDA is asked for and there is none."""
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device.startswith("cuda"):
        if not torch.cuda.is_available():
            raise DeviceError(f"--device {device}: no CUDA GPU is visible to PyTorch "
                              f"(torch {torch.__version__}, CUDA build: {torch.version.cuda or 'no'})")
        index = int(device[5:]) if ":" in device else 0
        if index >= torch.cuda.device_count():
            raise DeviceError(f"--device {device}: only {torch.cuda.device_count()} CUDA device(s)")
    return torch.device(device)


def prepare(model: torch.nn.Module, runtime: Runtime) -> tuple[torch.nn.Module, torch.device]:
    """Move ``model`` to the runtime's device and set the matmul precision; returns the module
    to call (compiled when asked) and the device. The original module keeps the weights."""
    device = runtime.torch_device()
    if runtime.precision == "bf16" and device.type != "cuda":
        raise DeviceError("--precision bf16 runs only on a CUDA device")
    torch.backends.cuda.matmul.allow_tf32 = runtime.tf32
    torch.backends.cudnn.allow_tf32 = runtime.tf32
    model.to(device)
    call = torch.compile(model, mode="reduce-overhead") if runtime.compile else model
    return call, device


@contextlib.contextmanager
def autocast(runtime: Runtime, device: torch.device) -> Iterator[None]:
    """bfloat16 autocast for ``precision: bf16``; nothing otherwise."""
    if runtime.precision == "bf16":
        with torch.autocast(device_type=device.type, dtype=torch.bfloat16):
            yield
    else:
        yield


def model_device(model: torch.nn.Module) -> torch.device:
    """The device of a module's first parameter (the CPU for a module without any)."""
    return next((p.device for p in model.parameters()), torch.device("cpu"))


def cpu_state(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    """The state dict as CPU tensors: what a checkpoint stores, whatever device trained it."""
    return {k: v.detach().cpu() for k, v in model.state_dict().items()}
