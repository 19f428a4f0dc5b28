"""Which world-model family a checkpoint folder holds, read from its config.json's key.

``world_model``: the autoregressive model over a discrete tokenizer's codes
(models/world_model.py, tasks/world/checkpoints.py); ``diffusion_world_model``: the diffusion
model over a continuous tokenizer's latents (models/diffusion_world.py, tasks/world/diffusion.py).
Both checkpoints carry the same extras beside it (``tokenizer``, ``size``, ``phase``,
``episodes``, ``camera``...), so what evaluates either reads them here.
"""

from __future__ import annotations

import json
from pathlib import Path

from tasks import checkpoint_files
from tasks.checkpoint_files import CONFIG_FILE, CheckpointError

AUTOREGRESSIVE, DIFFUSION = "autoregressive", "diffusion"
KEYS = {AUTOREGRESSIVE: "world_model", DIFFUSION: "diffusion_world_model"}
TOKENIZER_VARIANT = {AUTOREGRESSIVE: "discrete", DIFFUSION: "continuous"}


def family_of(body: dict) -> str:
    """The family of a checkpoint's config.json body (CheckpointError-free: AR when unsure)."""
    return DIFFUSION if isinstance(body.get(KEYS[DIFFUSION]), dict) else AUTOREGRESSIVE


def read_world_config(folder: Path | str) -> dict:
    """A world-model checkpoint's config.json of either family (CheckpointError naming the file otherwise)."""
    path = Path(folder) / CONFIG_FILE
    try:
        body = json.loads(path.read_text()) if path.is_file() else None
    except (OSError, UnicodeDecodeError, ValueError):
        body = None
    key = KEYS[family_of(body)] if isinstance(body, dict) else KEYS[AUTOREGRESSIVE]
    return checkpoint_files.read_config(Path(folder), key, "world-model checkpoint")


def model_section(body: dict) -> dict:
    """The architecture mapping of either family (``max_frames``, ``temporal_compression``...)."""
    return body[KEYS[family_of(body)]]


def model_config(folder: Path | str, body: dict | None = None):
    """The architecture config (``WorldModelConfig`` or ``DiffusionWorldConfig``) of a checkpoint."""
    body = read_world_config(folder) if body is None else body
    if family_of(body) == DIFFUSION:
        from models.diffusion_world import DiffusionWorldConfig as Config
    else:
        from models.world_model import WorldModelConfig as Config
    return checkpoint_files.model_config(Config, body, KEYS[family_of(body)], Path(folder))


def load_world_model(folder: Path | str):
    """The model a checkpoint folder of either family holds, in eval mode."""
    if family_of(read_world_config(folder)) == DIFFUSION:
        from tasks.world.diffusion import load_checkpoint
    else:
        from tasks.world.checkpoints import load_checkpoint
    return load_checkpoint(Path(folder))


def is_diffusion(model) -> bool:
    """A loaded model (or its config) of the diffusion family."""
    from models.diffusion_world import DiffusionWorldConfig, DiffusionWorldModel

    return isinstance(model, (DiffusionWorldModel, DiffusionWorldConfig))


__all__ = ["AUTOREGRESSIVE", "DIFFUSION", "KEYS", "TOKENIZER_VARIANT", "CheckpointError", "family_of",
           "is_diffusion", "load_world_model", "model_config", "model_section", "read_world_config"]
