"""Checkpoint files, one layout for every model: ``model.safetensors`` (its architecture JSON
in the header metadata under ``key``) and ``config.json`` (``{key: architecture, **extra}``),
each written atomically, so a crash never leaves a half-written checkpoint."""

from __future__ import annotations

import json
import os
from pathlib import Path

from safetensors.torch import save_file
from torch import nn

WEIGHTS_FILE, CONFIG_FILE = "model.safetensors", "config.json"


def write_checkpoint(model: nn.Module, folder: Path, key: str, extra: dict | None = None) -> tuple[Path, Path]:
    """Save ``model`` (which has a pydantic ``config``) under ``folder``; returns the two paths."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    weights, config = folder / WEIGHTS_FILE, folder / CONFIG_FILE
    tmp = folder / f".{WEIGHTS_FILE}.{os.getpid()}.tmp"
    save_file({k: v.contiguous() for k, v in model.state_dict().items()}, str(tmp),
              metadata={key: model.config.model_dump_json()})
    os.replace(tmp, weights)
    body = {key: model.config.model_dump(mode="json"), **(extra or {})}
    tmp = folder / f".{CONFIG_FILE}.{os.getpid()}.tmp"
    tmp.write_text(json.dumps(body, indent=2, sort_keys=True))
    os.replace(tmp, config)
    return weights, config
