"""The train flow's two phases as plain functions (the flow makes them Prefect tasks):
pre-training from seeded initial weights on codes and text, post-training with actions from the
pre-trained checkpoint; each logs to TensorBoard beside its checkpoint and saves it."""

from __future__ import annotations

from pathlib import Path

import torch

from models.world_model import WorldModel, WorldModelConfig
from schemas.hashing import content_hash
from tasks import progress
from tasks.tables import markdown_table
from tasks.device import Runtime
from tasks.tokenize import tokens
from tasks.world import checkpoints, data
from tasks.world.train import WorldTrainConfig, train_world_model
from tasks.world.train import posttrain as posttrain_model


def encode_episode(directory: Path, tokenizer_folder: Path, tokenizer_id: str, size: int, cameras: list[str] | None,
                   action_dim: int, text: str | None, root: Path, totals: int = 0) -> list[data.CodeSequence]:
    """Every camera (or the ones named) of one episode as codes with aligned actions (cached under root)."""
    tokenizer = tokens.load_checkpoint(tokenizer_folder)
    return data.load_episodes([directory], tokenizer, size, cameras, action_dim, text, tokenizer_id, root, totals)


def _tensorboard(folder: Path):
    from torch.utils.tensorboard import SummaryWriter

    writer = SummaryWriter(str(folder / "tensorboard"))

    def log(record: dict) -> None:
        progress.reached(progress.WORLD_MODEL_STEPS, record["step"])  # a command's terminal bar
        for name in ("loss", "accuracy", "copy_accuracy", "lr"):
            writer.add_scalar(f"train/{name}", record[name], record["step"])
    return writer, log


def pretrain(sequences: list[data.CodeSequence], model_config: WorldModelConfig, config: WorldTrainConfig,
             folder: Path, extra: dict, runtime: Runtime | None = None) -> tuple[list[dict], int]:
    """Train from seeded initial weights on codes and text, log to TensorBoard beside the
    checkpoint, save it; returns the history and the parameter count."""
    torch.manual_seed(config.seed)
    model = WorldModel(model_config)
    writer, log = _tensorboard(folder)
    with writer:
        history = train_world_model(model, sequences, config, log, runtime)
    checkpoints.save_checkpoint(model, folder, {"phase": "pretrain", "train": config.model_dump(mode="json"), **extra})
    return history, sum(p.numel() for p in model.parameters())


def posttrain(pretrained: Path, episodes: list[data.CodeSequence], config: WorldTrainConfig, folder: Path,
              extra: dict, runtime: Runtime | None = None) -> tuple[list[dict], int]:
    """Load the pre-trained checkpoint, add the zero-initialised action encoder, train on episodes, save."""
    writer, log = _tensorboard(folder)
    with writer:
        model, history = posttrain_model(checkpoints.load_checkpoint(pretrained), episodes, config, log, runtime)
    checkpoints.save_checkpoint(model, folder, {"phase": "posttrain", "train": config.model_dump(mode="json"), **extra})
    return history, sum(p.numel() for p in model.parameters())


def meaning(config: WorldTrainConfig) -> str:
    """The hash of what a phase trains, for its stage key."""
    # Threads change float summation order, not what is trained: the same run elsewhere is skipped.
    # A field added later is left out at its default, so checkpoints trained before it keep their ids.
    unset = {name for name in ("self_condition", "action_totals") if not getattr(config, name)}
    return content_hash(config.model_dump(mode="json", exclude={"threads", *unset}))


def token_patch(grid_h: int, grid_w: int, max_tokens: int = 64) -> int:
    """The smallest patch side dividing the latent grid that keeps a frame at ``max_tokens``
    transformer tokens or fewer (1 for the 8 x 8 grid of 64 x 64 frames, 2 for 16 x 16)."""
    for q in range(1, min(grid_h, grid_w) + 1):
        if grid_h % q == 0 and grid_w % q == 0 and (grid_h // q) * (grid_w // q) <= max_tokens:
            return q
    return 1


def curve(history: list[dict]) -> str:
    """A phase's training curve as a markdown table for the flow's report."""
    rows = [(h["step"], f"{h['seconds']:.1f}", f"{h['loss']:.4f}", f"{h['accuracy']:.3f}", f"{h['copy_accuracy']:.3f}")
            for h in history]
    return markdown_table(("step", "seconds", "loss (nats)", "next-frame accuracy", "copy-frame accuracy"), rows) \
        if rows else "skipped: done before"
