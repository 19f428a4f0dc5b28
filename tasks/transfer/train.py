"""Train a transfer model on simulator pairs: random windows, L1 loss, AdamW, cosine schedule.

Each step draws windows of ``clip_frames`` frames from random pairs (`tasks.transfer.pairs`)
and makes all their frames at once, each from the previous target frame (teacher forcing).
With probability ``self_feed`` a window's previous frames are instead the model's own outputs
(made without gradient from the teacher-forced pass), so it learns to continue from frames it
made, as it must when it generates a clip. Each control is dropped (weight 0) with
probability ``control_dropout`` per window, so any subset of controls, as a user's weights
choose, is a input the model has seen. A model with reference conditioning is given the
colour statistics of the window's whole target clip as its reference (so it learns to take
the look a reference shows), and none with probability ``reference_dropout`` (so the prompt
alone still works). A palette model's reference also carries the target clip's mean colour per
segmentation class, withheld with probability ``palette_dropout`` (as for a reference clip
that has no segmentation).

Pure: pairs in, a trained model and its history out; the checkpoint helpers write and read
``model.safetensors`` + ``config.json`` (`tasks.checkpoint_files`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from models.transfer import (REFERENCE_FEATURES, TransferConfig, TransferNet, palette_features, preset,
                             reference_features)
from tasks.checkpoint_files import load_weights, model_config, read_config, write_checkpoint
from tasks.device import Runtime, autocast, prepare
from tasks.tokenize.train import lr_at, psnr
from tasks.transfer.pairs import PairClip, depth_signal

CHECKPOINT_KEY = "transfer"
DEFAULT_SIZE = 64  # make_pairs' size: a checkpoint whose config names none was trained at it


def temporal_l1(out: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """L1 between the frame-to-frame changes of ``out`` and ``target`` (``B x C x T x H x W``):
    zero where the output changes exactly as the target does, however far its colours are."""
    return ((out[:, :, 1:] - out[:, :, :-1]) - (target[:, :, 1:] - target[:, :, :-1])).abs().mean()


class TrainConfig(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    preset: str = "tiny"
    steps: int = Field(200, ge=1)
    seconds: float | None = Field(None, gt=0, description="training-time budget; stops at steps or this")
    batch_size: int = Field(8, ge=1)
    clip_frames: int = Field(3, ge=1)
    self_feed: float = Field(0.25, ge=0, le=1, description="chance a window's previous frames are the model's own")
    control_dropout: float = Field(0.2, ge=0, le=1, description="chance each control gets weight 0 in a window")
    reference_dropout: float = Field(0.3, ge=0, le=1, description="chance a window has no reference clip "
                                     "(models with reference conditioning)")
    palette_dropout: float = Field(0.3, ge=0, le=1, description="chance a reference's class colours are withheld "
                                   "(palette models)")
    temporal: float = Field(0.0, ge=0, description="weight of the temporal loss: L1 between the output's and the "
                            "target's frame-to-frame changes, so that what the model adds does not flicker")
    lr: float = Field(2e-3, gt=0)
    warmup_steps: int = Field(20, ge=0)
    min_lr_ratio: float = Field(0.05, ge=0, le=1)
    seed: int = 0
    threads: int = Field(2, ge=1)
    log_every: int = Field(10, ge=1)


def clip_seg(config: TransferConfig, clip: PairClip) -> np.ndarray:
    """The clip's segmentation in the model's classes (``config.seg_groups``): F x H x W."""
    if config.seg_groups == "grouped":
        return clip.seg
    if clip.objects is None:
        raise ValueError(f"the model's segmentation is per object (seg_groups 'objects'); clip {clip.prompt!r} of seed "
                         f"{clip.seed} was made without it")
    return clip.objects


def pair_tensors(pair: PairClip, config: TransferConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """(controls ``C x F x H x W`` stacked in ``config.controls`` order, target ``3 x F x H x W``), float."""
    parts = {
        "edges": torch.from_numpy(pair.edges).float().div(127.5).sub(1)[None],
        "blur": torch.from_numpy(pair.blur).float().div(127.5).sub(1).movedim(-1, 0),
        "depth": torch.from_numpy(depth_signal(pair.depth_mm))[None],
        "segmentation": torch.nn.functional.one_hot(torch.from_numpy(clip_seg(config, pair)).long(), config.seg_classes)
        .float().movedim(-1, 0),
    }
    if "frame" in config.controls:
        if pair.source_frames is None:
            raise ValueError(f"the model takes the source's frames (control 'frame'); clip {pair.prompt!r} of seed "
                             f"{pair.seed} has none")
        parts["frame"] = frames_tensor(pair.source_frames)
    controls = torch.cat([parts[name] for name in config.controls], 0)
    return controls, frames_tensor(pair.frames)


def frames_tensor(frames: np.ndarray) -> torch.Tensor:
    """F x H x W x 3 uint8 -> ``3 x F x H x W`` float in [-1, 1]."""
    return torch.from_numpy(frames).float().div(127.5).sub(1).movedim(-1, 0)


def look_row(config: TransferConfig, frames: np.ndarray, seg: np.ndarray | None = None) -> torch.Tensor:
    """``1 x config.reference_size``: a clip's look as a reference row, from its frames (F x H x W
    x 3 uint8). A palette model's class colours need ``seg`` (F x H x W class ids of those
    frames: a simulated clip's segmentation); without it (any other clip) no class is known."""
    clip = frames_tensor(frames)[None]
    row = reference_features(clip)
    if not config.palette:
        return row
    if seg is None:
        return torch.cat([row, torch.zeros(1, 4 * config.seg_classes)], 1)
    if seg.shape != frames.shape[:3]:
        raise ValueError(f"segmentation of shape {seg.shape} for frames of shape {frames.shape[:3]}")
    return torch.cat([row, palette_features(clip, torch.from_numpy(seg)[None], config.seg_classes)], 1)


def clip_look(config: TransferConfig, clip: PairClip) -> torch.Tensor:
    """`look_row` of a simulated clip: its frames, with its segmentation in the model's classes."""
    return look_row(config, clip.frames, clip_seg(config, clip))


class PairSet:
    """Pairs as tensors once, and batches of random windows drawn from them."""

    def __init__(self, pairs: Sequence[PairClip], config: TransferConfig):
        if not pairs:
            raise ValueError("no pairs to train on")
        self.items = [(*pair_tensors(p, config), config.prompt_index(p.prompt)) for p in pairs]
        self.looks = [clip_look(config, p)[0] for p in pairs] if config.reference else None
        self.controls = len(config.controls)

    def sample(self, frames: int, batch: int, gen: torch.Generator, dropout: float = 0.0,
               reference_dropout: float = 0.0, palette_dropout: float = 0.0):
        """(controls ``B x C x T x H x W``, target ``B x 3 x T x H x W``, prompts ``B``, weights
        ``B x n``, references ``B x reference_size`` with NaN rows for none (and, with a palette,
        class colours zeroed as unknown with probability ``palette_dropout``), or None for a model
        without reference conditioning)."""
        usable = [i for i, item in enumerate(self.items) if item[0].shape[1] >= frames]
        if not usable:
            raise ValueError(f"no pair has {frames} frames")
        cs, ts, ps, picked = [], [], [], []
        for _ in range(batch):
            index = usable[int(torch.randint(len(usable), (1,), generator=gen))]
            controls, target, prompt = self.items[index]
            t0 = int(torch.randint(controls.shape[1] - frames + 1, (1,), generator=gen))
            cs.append(controls[:, t0:t0 + frames])
            ts.append(target[:, t0:t0 + frames])
            ps.append(prompt)
            picked.append(index)
        weights = (torch.rand(batch, self.controls, generator=gen) >= dropout).float()
        references = None
        if self.looks is not None:
            references = torch.stack([self.looks[i] for i in picked])
            if references.shape[1] > REFERENCE_FEATURES:
                references[torch.rand(batch, generator=gen) < palette_dropout, REFERENCE_FEATURES:] = 0.0
            references[torch.rand(batch, generator=gen) < reference_dropout] = float("nan")
        return torch.stack(cs), torch.stack(ts), torch.tensor(ps), weights, references


def train_transfer(model: TransferNet, pairs: Sequence[PairClip], config: TrainConfig,
                   on_log: Callable[[dict], None] | None = None, runtime: Runtime | None = None) -> list[dict]:
    """Train in place; returns one record per ``log_every`` steps: step, seconds, loss (L1 in
    [-1, 1] units), psnr (dB, teacher-forced and self-fed windows together), lr.

    Same seed, pairs and config: same weights (single-threaded). ``runtime`` says where
    (``tasks.device``): batches are drawn on the CPU and moved there; the model is left on it."""
    torch.set_num_threads(config.threads)
    runtime = runtime or Runtime(device="cpu")
    data = PairSet(pairs, model.config)
    call, device = prepare(model, runtime)
    gen = torch.Generator().manual_seed(config.seed)
    opt = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=0.0, betas=(0.9, 0.99))
    history: list[dict] = []
    trained, losses, psnrs = 0.0, [], []

    def log(step: int) -> None:
        nonlocal losses, psnrs
        record = {"step": step, "seconds": round(trained, 2), "loss": float(np.mean(losses)),
                  "psnr": float(np.mean(psnrs)), "lr": opt.param_groups[0]["lr"]}
        losses, psnrs = [], []
        history.append(record)
        if on_log:
            model.eval()
            on_log(record)
            model.train()

    model.train()
    step = 0
    for step in range(config.steps):
        if config.seconds and trained >= config.seconds:
            break
        started = time.perf_counter()
        progress = max(step / config.steps, trained / config.seconds if config.seconds else 0.0)
        for group in opt.param_groups:
            group["lr"] = lr_at(config, step, progress)
        controls, target, prompts, weights, references = (None if x is None else x.to(device) for x in data.sample(
            config.clip_frames, config.batch_size, gen, config.control_dropout, config.reference_dropout,
            config.palette_dropout))
        own = torch.rand(config.batch_size, generator=gen) < config.self_feed
        previous = target
        with autocast(runtime, device):
            if own.any():
                with torch.no_grad():
                    made = call(controls, prompts, weights, previous=target, reference=references).float()
                previous = torch.where(own.to(device)[:, None, None, None, None], made, target)
            out = call(controls, prompts, weights, previous=previous, reference=references)
        loss = (out.float() - target).abs().mean()
        if config.temporal and out.shape[2] > 1:
            loss = loss + config.temporal * temporal_l1(out.float(), target)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        losses.append(loss.item())
        psnrs.append(psnr(target, out.detach().float()).mean().item())
        trained += time.perf_counter() - started
        if (step + 1) % config.log_every == 0:
            log(step + 1)
    else:
        step = config.steps
    if losses:
        log(step)
    model.eval()
    return history


@torch.no_grad()
def evaluate(model: TransferNet, pairs: Sequence[PairClip], frames: int | None = None,
             reference: Callable[[PairClip], np.ndarray | PairClip | None] | None = None) -> dict[str, float]:
    """Mean PSNR (dB) per prompt of clips made frame by frame from the model's own previous
    frames (as generation runs), against the stressed rollouts' frames; the first ``frames``.
    ``reference(pair)``: a clip whose look the model is to take for that pair (its frames, F x
    H x W x 3 uint8, or a PairClip, whose segmentation gives a palette model class colours), or
    None (the prompt alone)."""
    model.eval()
    device = next(model.parameters()).device
    by_prompt: dict[str, list[float]] = {}
    for pair in pairs:
        controls, target = pair_tensors(pair, model.config)
        if frames:
            controls, target = controls[:, :frames], target[:, :frames]
        prompt = torch.tensor([model.config.prompt_index(pair.prompt)], device=device)
        look = reference(pair) if reference else None
        if isinstance(look, PairClip):
            features = clip_look(model.config, look).to(device)
        else:
            features = None if look is None else look_row(model.config, look).to(device)
        out = model(controls[None].to(device), prompt, reference=features).cpu()
        by_prompt.setdefault(pair.prompt, []).append(psnr(target[None], out).item())
    return {k: float(np.mean(v)) for k, v in by_prompt.items()}


def save_transfer(model: TransferNet, folder: Path, train: TrainConfig | None = None,
                  history: list[dict] | None = None, extra: dict | None = None) -> tuple[Path, Path]:
    """``extra``: more config.json keys, e.g. ``size``, the frame side the pairs were made at
    (what `worldline transfer` makes controls at; `checkpoint_size`)."""
    body = {"train": train.model_dump(mode="json") if train else None, "history": history or [], **(extra or {})}
    return write_checkpoint(model, folder, CHECKPOINT_KEY, body)


def checkpoint_size(folder: Path) -> int:
    """The frame side a transfer checkpoint was trained at: its config's ``size``, else 64
    (`tasks.transfer.pairs.make_pairs`'s default)."""
    size = read_config(folder, CHECKPOINT_KEY, "transfer checkpoint").get("size", DEFAULT_SIZE)
    return size if isinstance(size, int) and size > 0 else DEFAULT_SIZE


def load_transfer(folder: Path) -> TransferNet:
    """The model saved in ``folder``, on the CPU in eval mode; CheckpointError in one line otherwise."""
    body = read_config(folder, CHECKPOINT_KEY, "transfer checkpoint")
    return load_weights(TransferNet(model_config(TransferConfig, body, CHECKPOINT_KEY, folder)), folder)


def new_model(config: TrainConfig) -> TransferNet:
    """The preset's model, initialised from the run's seed."""
    torch.manual_seed(config.seed)
    return TransferNet(preset(config.preset))


def train_and_save(pairs: Sequence[PairClip], config: TrainConfig, folder: Path, extra: dict,
                   device: str | None = None) -> tuple[list[dict], int]:
    """(history, parameters) of a new ``config.preset`` model trained on ``pairs`` on ``device``
    (``tasks.device``; default $WORLDLINE_DEVICE, else auto) and saved under ``folder`` with ``extra``."""
    model = new_model(config)
    history = train_transfer(model, pairs, config, runtime=Runtime(device=device) if device else Runtime())
    save_transfer(model, folder, config, history, extra)
    return history, sum(p.numel() for p in model.parameters())
