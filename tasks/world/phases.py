"""The train flow's two phases as plain functions (the flow makes them Prefect tasks):
pre-training from seeded initial weights on codes and text, post-training with actions from the
pre-trained checkpoint; each logs to TensorBoard beside its checkpoint and saves it.

Either family: the autoregressive world model on a discrete tokenizer's codes, or the
diffusion one (models/diffusion_world.py) on a continuous tokenizer's latents; the configs
passed (``WorldModelConfig``/``WorldTrainConfig`` or ``DiffusionWorldConfig``/``DiffusionTrainConfig``)
say which, and what differs between them for the flow is here (``family_setup`` and below)."""

from __future__ import annotations

from pathlib import Path

import torch

from models.diffusion_world import DiffusionWorldConfig, DiffusionWorldModel
from models.diffusion_world import preset as diffusion_preset
from models.world_model import WorldModel, WorldModelConfig
from models.world_model import preset as ar_preset
from schemas.hashing import content_hash
from tasks import progress
from tasks.tables import markdown_table
from tasks.device import Runtime
from tasks.tokenize import tokens
from tasks.world import checkpoints, data
from tasks.world import diffusion as diffusion_checkpoints
from tasks.world.diffusion import DiffusionTrainConfig, train_diffusion
from tasks.world.diffusion import posttrain as diffusion_posttrain
from tasks.world.train import WorldTrainConfig, train_world_model
from tasks.world.train import posttrain as posttrain_model


def encode_episode(directory: Path, tokenizer_folder: Path, tokenizer_id: str, size: int, cameras: list[str] | None,
                   action_dim: int, text: str | None, root: Path, totals: int = 0) -> list:
    """Every camera (or the ones named) of one episode as codes (a discrete tokenizer) or latents
    (a continuous one) with aligned actions (cached under root)."""
    tokenizer = tokens.load_checkpoint(tokenizer_folder)
    if tokenizer.config.variant == "continuous":
        from tasks.world.latents import load_latent_episodes

        return load_latent_episodes([directory], tokenizer, size, cameras, action_dim, text, tokenizer_id, root, totals)
    return data.load_episodes([directory], tokenizer, size, cameras, action_dim, text, tokenizer_id, root, totals)


def load_sequences(files: list[Path], root: Path, variant: str = "discrete") -> list:
    """A tokenizer's token shards as code sequences (discrete) or latent sequences (continuous)."""
    if variant == "continuous":
        from tasks.world.latents import load_latent_sequences

        return load_latent_sequences(files, root)
    return data.load_token_sequences(files, root)


def _tensorboard(folder: Path):
    from torch.utils.tensorboard import SummaryWriter

    writer = SummaryWriter(str(folder / "tensorboard"))

    def log(record: dict) -> None:
        progress.reached(progress.WORLD_MODEL_STEPS, record["step"])  # a command's terminal bar
        for name in ("loss", "accuracy", "copy_accuracy", "lr"):
            if name in record:
                writer.add_scalar(f"train/{name}", record[name], record["step"])
    return writer, log


def pretrain(sequences: list, model_config: WorldModelConfig | DiffusionWorldConfig,
             config: WorldTrainConfig | DiffusionTrainConfig, folder: Path, extra: dict,
             runtime: Runtime | None = None) -> tuple[list[dict], int]:
    """Train from seeded initial weights on codes (or latents) and text, log to TensorBoard beside
    the checkpoint, save it; returns the history and the parameter count."""
    torch.manual_seed(config.seed)
    diffusion = isinstance(model_config, DiffusionWorldConfig)
    model = DiffusionWorldModel(model_config) if diffusion else WorldModel(model_config)
    writer, log = _tensorboard(folder)
    with writer:
        history = (train_diffusion if diffusion else train_world_model)(model, sequences, config, log, runtime)
    save = diffusion_checkpoints.save_checkpoint if diffusion else checkpoints.save_checkpoint
    save(model, folder, {"phase": "pretrain", "train": config.model_dump(mode="json"), **extra})
    return history, sum(p.numel() for p in model.parameters())


def posttrain(pretrained: Path, episodes: list, config: WorldTrainConfig | DiffusionTrainConfig, folder: Path,
              extra: dict, runtime: Runtime | None = None) -> tuple[list[dict], int]:
    """Load the pre-trained checkpoint, add the zero-initialised action encoder, train on episodes, save."""
    diffusion = isinstance(config, DiffusionTrainConfig)
    module = diffusion_checkpoints if diffusion else checkpoints
    writer, log = _tensorboard(folder)
    with writer:
        model, history = (diffusion_posttrain if diffusion else posttrain_model)(
            module.load_checkpoint(pretrained), episodes, config, log, runtime)
    module.save_checkpoint(model, folder, {"phase": "posttrain", "train": config.model_dump(mode="json"), **extra})
    return history, sum(p.numel() for p in model.parameters())


def meaning(config: WorldTrainConfig | DiffusionTrainConfig) -> str:
    """The hash of what a phase trains, for its stage key."""
    # Threads change float summation order, not what is trained: the same run elsewhere is skipped.
    # A field added later is left out at its default, so checkpoints trained before it keep their ids.
    unset = {name for name in ("self_condition", "action_totals") if not getattr(config, name, 0)}
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
    if history and "accuracy" not in history[0]:  # diffusion: the velocity's mean squared error
        return markdown_table(("step", "seconds", "loss (velocity MSE)"),
                              [(h["step"], f"{h['seconds']:.1f}", f"{h['loss']:.4f}") for h in history])
    rows = [(h["step"], f"{h['seconds']:.1f}", f"{h['loss']:.4f}", f"{h['accuracy']:.3f}", f"{h['copy_accuracy']:.3f}")
            for h in history]
    return markdown_table(("step", "seconds", "loss (nats)", "next-frame accuracy", "copy-frame accuracy"), rows) \
        if rows else "skipped: done before"


def scores(history: list[dict]) -> str:
    """The last logged record's scores, for the flow's log line."""
    last = history[-1]
    return f"loss {last['loss']:.3f}" + (f", accuracy {last['accuracy']:.3f}" if "accuracy" in last else "")


def family_setup(family: str, preset_name: str, tok_config, grid: tuple[int, int], patch: int | None,
                 window: int | None, steps: tuple[int, int], batch_size: int, seed: int, threads: int,
                 change_weight: float = 0.0, self_condition: float = 0.0, action_totals: int = 0) -> dict:
    """What the train flow needs of a family: the model config for the tokenizer's grid, the pre-
    and post-training configs, what enters the stage keys besides them (nothing for the
    autoregressive family: its checkpoint ids are as before families), the lineage attrs added
    and the metrics recorded."""
    (grid_h, grid_w), (pre_steps, post_steps) = grid, steps
    frames = {"max_frames": window} if window else {}
    if family == "diffusion":
        model_config = diffusion_preset(preset_name, latent_channels=tok_config.latent_channels, max_height=grid_h,
                                        max_width=grid_w, temporal_compression=tok_config.temporal_compression,
                                        **({"patch": patch} if patch else {}), **frames)
        pre = DiffusionTrainConfig(preset=preset_name, steps=pre_steps, batch_size=batch_size, seed=seed,
                                   threads=threads)
        post = DiffusionTrainConfig(preset=preset_name, steps=post_steps, batch_size=batch_size, seed=seed,
                                    threads=threads, lr=pre.lr / 2, warmup_steps=10, action_totals=action_totals)
        return {"model": model_config, "pre": pre, "post": post, "key": ("diffusion",),
                "attrs": {"family": "diffusion"}, "metrics": ("loss",)}
    model_config = ar_preset(preset_name, codebook_size=tok_config.codebook_size, max_height=grid_h, max_width=grid_w,
                             temporal_compression=tok_config.temporal_compression,
                             patch=patch or token_patch(grid_h, grid_w), **frames)
    pre = WorldTrainConfig(preset=preset_name, steps=pre_steps, batch_size=batch_size, seed=seed, threads=threads,
                           change_weight=change_weight)
    post = WorldTrainConfig(preset=preset_name, steps=post_steps, batch_size=batch_size, seed=seed, threads=threads,
                            lr=pre.lr / 2, warmup_steps=10, change_weight=change_weight,
                            self_condition=self_condition, action_totals=action_totals)
    return {"model": model_config, "pre": pre, "post": post, "key": (), "attrs": {},
            "metrics": checkpoints.METRICS}
