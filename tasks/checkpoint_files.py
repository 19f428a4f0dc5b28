"""Checkpoint files, one layout for every model: ``model.safetensors`` (its architecture JSON
in the header metadata under ``key``) and ``config.json`` (``{key: architecture, **extra}``),
each written atomically, so a crash never leaves a half-written checkpoint, and read back with
one-line errors naming the file and the problem."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TypeVar

from pydantic import BaseModel
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file
from torch import nn

from tasks.device import cpu_state

WEIGHTS_FILE, CONFIG_FILE = "model.safetensors", "config.json"
Config = TypeVar("Config", bound=BaseModel)


class CheckpointError(ValueError):
    """One line: the checkpoint file and what is wrong with it."""


def write_checkpoint(model: nn.Module, folder: Path, key: str, extra: dict | None = None) -> tuple[Path, Path]:
    """Save ``model`` (which has a pydantic ``config``) under ``folder``; returns the two paths."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    weights, config = folder / WEIGHTS_FILE, folder / CONFIG_FILE
    tmp = folder / f".{WEIGHTS_FILE}.{os.getpid()}.tmp"
    # CPU copies: a checkpoint trained on a GPU loads on a machine without one.
    save_file({k: v.contiguous() for k, v in cpu_state(model).items()}, str(tmp),
              metadata={key: model.config.model_dump_json()})
    os.replace(tmp, weights)
    body = {key: model.config.model_dump(mode="json"), **(extra or {})}
    tmp = folder / f".{CONFIG_FILE}.{os.getpid()}.tmp"
    tmp.write_text(json.dumps(body, indent=2, sort_keys=True))
    os.replace(tmp, config)
    return weights, config


def read_config(folder: Path, key: str, what: str = "checkpoint") -> dict:
    """``config.json`` of a checkpoint folder, checked to be a mapping holding ``key``."""
    path = Path(folder) / CONFIG_FILE
    if not path.is_file():
        raise CheckpointError(f"{folder}: not a {what} folder (no {CONFIG_FILE})")
    try:
        body = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise CheckpointError(f"{path}: unreadable ({exc})") from None
    if not isinstance(body, dict) or not isinstance(body.get(key), dict):
        raise CheckpointError(f"{path}: not a {what} config (no {key!r} mapping)")
    return body


def model_config(config_type: type[Config], body: dict, key: str, folder: Path) -> Config:
    """The architecture ``body[key]`` validated as ``config_type``; errors name the config file."""
    from tasks.manifests import validated

    return validated(config_type, body[key], f"{Path(folder) / CONFIG_FILE}: {key}", CheckpointError)


def load_weights(model: nn.Module, folder: Path) -> nn.Module:
    """``model`` with the weights of ``folder``'s ``model.safetensors``, in eval mode; errors name the file."""
    path = Path(folder) / WEIGHTS_FILE
    if not path.is_file():
        raise CheckpointError(f"{folder}: no {WEIGHTS_FILE}")
    try:
        model.load_state_dict(load_file(str(path), device="cpu"))
    except (OSError, SafetensorError) as exc:
        raise CheckpointError(f"{path}: unreadable weights ({exc})") from None
    except RuntimeError as exc:  # torch: tensors missing, unexpected or of another shape
        problem = " ".join(str(exc).split())[:200]
        raise CheckpointError(f"{path}: the weights do not fit the architecture in {CONFIG_FILE} ({problem})") from None
    return model.eval()
