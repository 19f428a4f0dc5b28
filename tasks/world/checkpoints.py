"""World model checkpoints (safetensors + config JSON, as tasks/tokenize/tokens.py writes them) and their lineage.

``config.json`` holds ``{"world_model": WorldModelConfig, **extra}`` (the flow adds the train
config, the phase, the checkpoint id and the tokenizer it reads); the safetensors metadata
holds the model config too, so the weights file alone is enough to rebuild the model.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path


from models.world_model import WorldModel, WorldModelConfig
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, MetricRecord
from tasks import checkpoint_files
from tasks.checkpoint_files import CONFIG_FILE, WEIGHTS_FILE, write_checkpoint

METRICS = ("loss", "accuracy")  # history fields recorded as train_<name> per logged step


def save_checkpoint(model: WorldModel, folder: Path, extra: dict | None = None) -> tuple[Path, Path]:
    """Weights as safetensors and ``{"world_model": config, **extra}`` as JSON, each written atomically."""
    return write_checkpoint(model, folder, "world_model", extra)


def read_config(folder: Path) -> dict:
    """A world-model checkpoint's config.json (CheckpointError naming the file otherwise)."""
    return checkpoint_files.read_config(folder, "world_model", "world-model checkpoint")


def load_checkpoint(folder: Path) -> WorldModel:
    """The model a checkpoint folder holds (with its action encoder when post-trained), in eval mode."""
    config = checkpoint_files.model_config(WorldModelConfig, read_config(folder), "world_model", folder)
    return checkpoint_files.load_weights(WorldModel(config), folder)


def _sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def checkpoint_lineage(checkpoint_id: str, folder: Path, root: Path, parents: Sequence[tuple[str, str]],
                       history: Sequence[dict], stage_run_id: str, manifest_hash: str | None,
                       attrs: dict, kind: str = "checkpoint", metrics: Sequence[str] = METRICS) -> LineageBatch:
    """The checkpoint artifact (its weights file; ``attrs`` plus the config uri), an edge from
    every (parent id, relation) in ``parents``, and train_<name> per logged step for each of
    ``metrics`` (train_loss and train_accuracy for a world model)."""
    weights = Path(folder) / WEIGHTS_FILE
    batch = LineageBatch(artifacts=[ArtifactRecord(
        artifact_id=checkpoint_id, kind=kind, uri=weights.relative_to(root).as_posix(),
        sha256=_sha256(weights), bytes=weights.stat().st_size, manifest_hash=manifest_hash,
        stage_run_id=stage_run_id,
        attrs={**attrs, "config_uri": (Path(folder) / CONFIG_FILE).relative_to(root).as_posix()},
    )])
    batch.edges.extend(EdgeRecord(parent_id=p, child_id=checkpoint_id, relation=r) for p, r in dict.fromkeys(parents))
    for record in history:
        for name in metrics:
            batch.metrics.append(MetricRecord(subject_id=checkpoint_id, name=f"train_{name}", step=record["step"],
                                              value=record[name], stage_run_id=stage_run_id,
                                              manifest_hash=manifest_hash))
    return batch
