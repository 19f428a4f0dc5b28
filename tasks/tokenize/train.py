"""Train a video tokenizer on decoded clips: random windows, L1 loss, AdamW, cosine schedule.

Two optional levers put capacity where things move (what a world model has to predict),
rather than on static texture: ``motion_weight`` weights the L1 loss up to ``1 +
motion_weight`` on pixels that change between neighbouring frames, and ``focus_crops`` draws
that many candidate crops per window and keeps the one that changes most.

Pure: clips in (``T x H x W x 3`` uint8 arrays), a trained model and its history out; no
files, no Prefect. The schedule runs on progress = max(step / steps, training seconds /
budget), so a wall-clock budget (the bench's) and a step count (tests, the flow) both end
the cosine at its floor.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field

from models.tokenizer import VideoTokenizer
from tasks.device import Runtime, autocast, prepare


class TrainConfig(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    preset: str = "tiny-dv4x8x8"
    steps: int = Field(200, ge=1)
    seconds: float | None = Field(None, gt=0, description="training-time budget; stops at steps or this")
    batch_size: int = Field(4, ge=1)
    clip_frames: int = Field(9, ge=1, description="1 + k * temporal compression")
    size: int = Field(64, ge=8, description="frames are resized to size x size")
    crop: int | None = Field(None, ge=8, description="train on random crops of this side")
    motion_weight: float = Field(0.0, ge=0, description="extra L1 weight on pixels that change between frames")
    focus_crops: int = Field(1, ge=1, description="candidate crops per window; the one that changes most is kept")
    lr: float = Field(2e-3, gt=0)
    warmup_steps: int = Field(20, ge=0)
    min_lr_ratio: float = Field(0.05, ge=0, le=1)
    latent_noise: float = Field(1 / 255, ge=0, description="continuous only: half-width of uniform latent noise")
    seed: int = 0
    threads: int = Field(2, ge=1)
    log_every: int = Field(10, ge=1)


def to_tensor(frames: np.ndarray) -> torch.Tensor:
    """``[B x] T x H x W x 3`` uint8 -> ``[B x] 3 x T x H x W`` float in [-1, 1]."""
    x = torch.from_numpy(np.ascontiguousarray(frames)).float().div(127.5).sub(1)
    return x.movedim(-1, -4)


def to_uint8(x: torch.Tensor) -> np.ndarray:
    """Inverse of ``to_tensor`` (clamped and rounded): ``[B x] T x H x W x 3`` uint8."""
    return x.clamp(-1, 1).add(1).mul(127.5).round().to(torch.uint8).movedim(-4, -1).cpu().numpy()


def change_energy(window: np.ndarray) -> float:
    """Sum of absolute frame-to-frame differences of a ``T x H x W x 3`` uint8 window."""
    return float(np.abs(np.diff(window.astype(np.int16), axis=0)).sum()) if window.shape[0] > 1 else 0.0


def sample_batch(clips: Sequence[np.ndarray], frames: int, batch: int, gen: torch.Generator,
                 crop: int | None = None, focus: int = 1) -> torch.Tensor:
    """``batch`` random windows of ``frames`` frames (and ``crop`` x ``crop`` pixels): ``B x 3 x T x H x W`` in [-1, 1].

    With ``focus`` > 1, each window's crop is the one of ``focus`` random candidates whose
    frames change most (``change_energy``)."""
    usable = [c for c in clips if c.shape[0] >= frames]
    if not usable:
        raise ValueError(f"no clip has {frames} frames")
    out = []
    for _ in range(batch):
        clip = usable[int(torch.randint(len(usable), (1,), generator=gen))]
        t0 = int(torch.randint(clip.shape[0] - frames + 1, (1,), generator=gen))
        window = clip[t0:t0 + frames]
        if crop:
            candidates = []
            for _ in range(focus):
                y = int(torch.randint(window.shape[1] - crop + 1, (1,), generator=gen))
                x = int(torch.randint(window.shape[2] - crop + 1, (1,), generator=gen))
                candidates.append(window[:, y:y + crop, x:x + crop])
            window = max(candidates, key=change_energy) if focus > 1 else candidates[0]
        out.append(window)
    return to_tensor(np.stack(out))


def motion_weights(x: torch.Tensor, strength: float, scale: float = 0.1) -> torch.Tensor:
    """Per-pixel loss weights ``B x 1 x T x H x W`` in [1, 1 + strength] for a batch ``B x 3 x T x H x W`` in [-1, 1].

    A pixel's change is its largest absolute difference (over channels) from the previous or
    the next frame, saturating at ``scale`` (5% of the range), spread by one pixel so edges of
    moving objects count in full."""
    step = (x[:, :, 1:] - x[:, :, :-1]).abs().amax(1, keepdim=True)
    change = torch.zeros_like(x[:, :1])
    change[:, :, 1:] = step
    change[:, :, :-1] = torch.maximum(change[:, :, :-1], step)
    change = F.max_pool3d(change.div(scale).clamp(max=1), (1, 3, 3), stride=1, padding=(0, 1, 1))
    return 1 + strength * change


def reconstruction_loss(x: torch.Tensor, recon: torch.Tensor, motion_weight: float = 0.0) -> torch.Tensor:
    """L1, or with ``motion_weight`` the ``motion_weights``-weighted mean of it."""
    error = (recon - x).abs()
    if not motion_weight:
        return error.mean()
    w = motion_weights(x, motion_weight)
    return (error * w).mean() / w.mean()


def psnr(reference: torch.Tensor, recon: torch.Tensor) -> torch.Tensor:
    """Per-clip PSNR (dB) of 8-bit pixels; inputs ``B x 3 x T x H x W`` in [-1, 1]."""
    a = reference.clamp(-1, 1).add(1).mul(127.5).round()
    b = recon.clamp(-1, 1).add(1).mul(127.5).round()
    mse = (a - b).pow(2).flatten(1).mean(1).clamp_min(1e-10)
    return 10 * torch.log10(255.0 ** 2 / mse)


def lr_at(config: TrainConfig, step: int, progress: float) -> float:
    if step < config.warmup_steps:
        return config.lr * (step + 1) / config.warmup_steps
    floor = config.lr * config.min_lr_ratio
    return floor + (config.lr - floor) * 0.5 * (1 + math.cos(math.pi * min(progress, 1.0)))


def train_tokenizer(model: VideoTokenizer, clips: Sequence[np.ndarray], config: TrainConfig,
                    on_log: Callable[[dict], None] | None = None, runtime: Runtime | None = None) -> list[dict]:
    """Train in place; returns one record per ``log_every`` steps: step, seconds, loss, psnr, lr.

    ``on_log`` gets each record as it is made (TensorBoard, evaluation); its own time is not
    counted against the budget. Same seed, clips and config: same weights (single-threaded).
    ``runtime`` says where (``tasks.device``): the model moves there and each batch is sampled
    on the CPU (the same windows on any device) and moved there; the model is left on it.
    """
    torch.set_num_threads(config.threads)
    runtime = runtime or Runtime(device="cpu")
    call, device = prepare(model, runtime)
    gen = torch.Generator().manual_seed(config.seed)
    opt = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=0.0, betas=(0.9, 0.99))
    history: list[dict] = []
    trained = 0.0
    model.train()
    losses, psnrs = [], []
    for step in range(config.steps):
        started = time.perf_counter()
        progress = max(step / config.steps, trained / config.seconds if config.seconds else 0.0)
        if config.seconds and trained >= config.seconds:
            break
        for group in opt.param_groups:
            group["lr"] = lr_at(config, step, progress)
        x = sample_batch(clips, config.clip_frames, config.batch_size, gen, config.crop,
                         config.focus_crops).to(device, non_blocking=True)
        with autocast(runtime, device):
            recon, _ = call(x, latent_noise=config.latent_noise)
        loss = reconstruction_loss(x, recon.float(), config.motion_weight)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        losses.append(loss.item())
        psnrs.append(psnr(x, recon.detach()).mean().item())
        trained += time.perf_counter() - started
        if (step + 1) % config.log_every == 0 or step + 1 == config.steps:
            record = {"step": step + 1, "seconds": round(trained, 2), "loss": float(np.mean(losses)),
                      "psnr": float(np.mean(psnrs)), "lr": opt.param_groups[0]["lr"]}
            losses, psnrs = [], []
            history.append(record)
            if on_log:
                model.eval()
                on_log(record)
                model.train()
    if losses:
        record = {"step": step, "seconds": round(trained, 2), "loss": float(np.mean(losses)),
                  "psnr": float(np.mean(psnrs)), "lr": opt.param_groups[0]["lr"]}
        history.append(record)
        if on_log:
            model.eval()
            on_log(record)
    model.eval()
    return history
