"""Train the diffusion world model (models/diffusion_world.py) on continuous latents, and its checkpoints.

Pure, as tasks/world/train.py is: ``LatentSequence``s in, a trained model and its history out.
Random windows of ``max_frames`` latent frames; in each, the first c frames (c drawn per window
in [min_context, T' - 1]) are context and the rest are noised to a flow time s drawn from a
logit-normal (SD3, arXiv:2403.03206: most steps at middling noise) or uniform law; the loss is
the mean squared error of the predicted velocity on the future frames only. AdamW, warm-up and
cosine as ``tasks.world.train.lr_at``. Checkpoints use the shared format (``tasks.checkpoint_files``)
under the config key ``diffusion_world_model``, so config.json says which family a folder holds.

``LatentSequence`` is its own type rather than a ``CodeSequence`` holding floats: codes are
``T' x H' x W'`` int64, latents ``T' x C x H' x W'`` float32 (frames first, so windows slice
the first axis; ``sample_windows`` moves channels ahead of time as the model takes them).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field

from models.diffusion_world import DiffusionWorldConfig, DiffusionWorldModel, post_trainable
from models.tokenizer import VideoTokenizer
from models.world_model import action_scale, text_ids
from tasks import checkpoint_files
from tasks.device import Runtime, autocast, prepare
from tasks.tokenize.data import square, usable_frames
from tasks.tokenize.train import to_tensor
from tasks.world.train import optimise, pick_windows, window_length

CONFIG_KEY = "diffusion_world_model"


@dataclass(frozen=True)
class LatentSequence:
    """One video as continuous latents ``T' x C x H' x W'`` float32, its text, and (episodes)
    actions ``(T' - 1) x action_features`` float32 whose row j leads from latent frame j to j + 1."""

    key: str
    latents: np.ndarray
    text: str
    actions: np.ndarray | None = None
    info: dict = field(default_factory=dict)

    @property
    def frames(self) -> int:
        return int(self.latents.shape[0])


class DiffusionTrainConfig(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    preset: str = "tiny-dwm"
    steps: int = Field(200, ge=1)
    seconds: float | None = Field(None, gt=0, description="training-time budget; stops at steps or this")
    batch_size: int = Field(8, ge=1)
    lr: float = Field(1e-3, gt=0)
    warmup_steps: int = Field(20, ge=0)
    min_lr_ratio: float = Field(0.1, ge=0, le=1)
    weight_decay: float = Field(0.01, ge=0)
    text_dropout: float = Field(0.1, ge=0, le=1, description="share of windows trained without their text")
    time_sampling: Literal["logit_normal", "uniform"] = "logit_normal"
    min_context: int = Field(1, ge=1, description="fewest context frames in a training window")
    action_totals: int = Field(0, ge=0, le=8, description="post-training: leading action values also given as "
                               "running totals (the episodes must be loaded with them)")
    seed: int = 0
    threads: int = Field(2, ge=1)
    log_every: int = Field(10, ge=1)


@torch.no_grad()
def encode_latents(tokenizer: VideoTokenizer, frames: np.ndarray, size: int,
                   max_frames: int | None = None) -> np.ndarray:
    """``T x H x W x 3`` uint8 -> latents ``T' x C x size/s x size/s`` float32 of the first ``1 + t k``
    frames (the continuous twin of ``tasks.world.data.encode_frames``)."""
    c = tokenizer.config
    if c.variant != "continuous":
        raise ValueError("the diffusion world model needs a continuous tokenizer")
    n = usable_frames(frames.shape[0], c.temporal_compression, max_frames)
    if n == 0:
        raise ValueError("no frames to encode")
    latents = tokenizer.eval().encode(to_tensor(square(frames[:n], size))[None])[0]
    return latents.transpose(0, 1).numpy().astype(np.float32)


def sample_windows(sequences: Sequence[LatentSequence], frames: int, batch: int, gen: torch.Generator,
                   with_actions: bool = False, text_dropout: float = 0.0
                   ) -> tuple[torch.Tensor, list[str], torch.Tensor | None]:
    """``batch`` random windows of ``frames`` latent frames: latents ``B x C x frames x H' x W'``
    float32, texts and actions as ``tasks.world.train.pick_windows`` gives them."""
    latents, texts, acts = pick_windows(sequences, frames, batch, gen, with_actions, text_dropout, lambda s: s.latents)
    return torch.from_numpy(np.stack(latents).astype(np.float32)).transpose(1, 2), texts, acts


def flow_times(batch: int, gen: torch.Generator, sampling: str = "logit_normal") -> torch.Tensor:
    """``B`` flow times in (0, 1): sigmoid of a standard normal (logit-normal) or uniform."""
    if sampling == "logit_normal":
        return torch.sigmoid(torch.randn(batch, generator=gen))
    if sampling == "uniform":
        return torch.rand(batch, generator=gen)
    raise ValueError(f"unknown time sampling {sampling!r}: logit_normal or uniform")


def noised_window(latents: torch.Tensor, gen: torch.Generator, sampling: str = "logit_normal", min_context: int = 1
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """A training input for clean latents ``B x C x T' x H' x W'``: (inputs, times ``B``, context
    flags ``B x T'``, target velocities). Each row keeps its first c frames clean (c drawn in
    [min_context, T' - 1]); its other frames become ``(1 - s) x + s e``, target ``e - x``. Draws
    come from ``gen`` on the CPU and move to the latents' device."""
    b, _, t = latents.shape[:3]
    if t < 2:
        raise ValueError("a window needs 2 latent frames: a context and a future one")
    low = min(min_context, t - 1)
    counts = torch.randint(low, t, (b,), generator=gen)
    flags = (torch.arange(t)[None] < counts[:, None]).to(latents.device)
    s = flow_times(b, gen, sampling).to(latents.device)
    noise = torch.randn(latents.shape, generator=gen).to(latents.device, latents.dtype)
    ss = s.view(b, 1, 1, 1, 1).to(latents.dtype)
    keep = flags[:, None, :, None, None]
    inputs = torch.where(keep, latents, (1 - ss) * latents + ss * noise)
    return inputs, s, flags, noise - latents


def flow_matching_loss(velocity: torch.Tensor, target: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
    """Mean squared error of ``velocity`` against ``target`` (``B x C x T' x H' x W'``) over the
    future frames only (``context`` ``B x T'`` bool marks the frames that are not scored)."""
    future = (~context)[:, None, :, None, None].to(velocity.dtype).expand_as(velocity)
    return (F.mse_loss(velocity, target, reduction="none") * future).sum() / future.sum().clamp(min=1)


def train_diffusion(model: DiffusionWorldModel, sequences: Sequence[LatentSequence], config: DiffusionTrainConfig,
                    on_log: Callable[[dict], None] | None = None, runtime: Runtime | None = None) -> list[dict]:
    """Train in place; one record per ``log_every`` steps (and the last): step, seconds, loss (mean
    squared velocity error on future frames), lr. An action-conditioned model trains on the
    sequences' actions. Same seed, sequences and config: same weights (single-threaded, CPU).
    ``runtime`` says where (``tasks.device``): windows and noise are drawn on the CPU and moved there."""
    torch.set_num_threads(config.threads)
    runtime = runtime or Runtime(device="cpu")
    call, device = prepare(model, runtime)
    gen = torch.Generator().manual_seed(config.seed)
    frames = window_length(sequences, model.config.max_frames)
    frames -= frames % model.config.temporal_patch
    if frames < 2:
        raise ValueError(f"no window of 2 latent frames fits temporal_patch {model.config.temporal_patch}")
    with_actions = model.config.action_conditioned

    def batch_loss() -> tuple[torch.Tensor, dict[str, float]]:
        latents, texts, actions = sample_windows(sequences, frames, config.batch_size, gen, with_actions,
                                                 config.text_dropout)
        latents = latents.to(device, non_blocking=True)
        actions = actions.to(device, non_blocking=True) if actions is not None else None
        inputs, s, flags, target = noised_window(latents, gen, config.time_sampling, config.min_context)
        with autocast(runtime, device):
            velocity = call(inputs, s, flags, text_ids(texts, model.config).to(device), actions)
        return flow_matching_loss(velocity.float(), target, flags), {}

    return optimise(model, config, batch_loss, on_log)


def posttrain(pretrained: DiffusionWorldModel, episodes: Sequence[LatentSequence], config: DiffusionTrainConfig,
              on_log: Callable[[dict], None] | None = None,
              runtime: Runtime | None = None) -> tuple[DiffusionWorldModel, list[dict]]:
    """A copy of the pre-trained model with a zero-initialised action encoder (so it starts out
    computing what the pre-trained model does), trained on episodes with their actions, each
    action value divided by its root mean square over these episodes."""
    torch.manual_seed(config.seed)
    c = pretrained.config
    scale = action_scale([e.actions for e in episodes], c.action_dim, c.temporal_compression)
    model = post_trainable(pretrained, scale, config.action_totals)
    return model, train_diffusion(model, episodes, config, on_log, runtime)


# -- checkpoints ---------------------------------------------------------------------------------
def save_checkpoint(model: DiffusionWorldModel, folder: Path, extra: dict | None = None) -> tuple[Path, Path]:
    """Weights as safetensors and ``{"diffusion_world_model": config, **extra}`` as JSON, each atomically."""
    return checkpoint_files.write_checkpoint(model, folder, CONFIG_KEY, extra)


def read_config(folder: Path) -> dict:
    """A diffusion world-model checkpoint's config.json (CheckpointError naming the file otherwise)."""
    return checkpoint_files.read_config(folder, CONFIG_KEY, "diffusion world-model checkpoint")


def load_checkpoint(folder: Path) -> DiffusionWorldModel:
    """The model a checkpoint folder holds (with its action encoder when post-trained), in eval mode."""
    config = checkpoint_files.model_config(DiffusionWorldConfig, read_config(folder), CONFIG_KEY, folder)
    return checkpoint_files.load_weights(DiffusionWorldModel(config), folder)
