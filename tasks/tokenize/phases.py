"""The tokenize flow's two steps as plain functions (the flow makes them Prefect tasks):
training a tokenizer, logged to TensorBoard beside its checkpoint, and encoding a shard's
clips into a token shard."""

from __future__ import annotations

from pathlib import Path

import torch

from models.tokenizer import VideoTokenizer, preset
from tasks import progress
from tasks.tokenize import data, tokens
from tasks.device import Runtime
from tasks.tokenize.train import TrainConfig, psnr, to_tensor, train_tokenizer


def train(clips: list[data.Clip], config: TrainConfig, folder: Path, extra: dict,
          init: Path | None = None, runtime: Runtime | None = None) -> tuple[list[dict], int]:
    """Train from the preset's seeded initial weights (or from checkpoint folder ``init``), log to
    TensorBoard beside the checkpoint, save it; returns the history and the parameter count."""
    from torch.utils.tensorboard import SummaryWriter

    torch.manual_seed(config.seed)
    model = tokens.load_checkpoint(init).train() if init else VideoTokenizer(preset(config.preset))
    with SummaryWriter(str(folder / "tensorboard")) as writer:
        every = max(config.log_every, config.steps // 20 // config.log_every * config.log_every)

        def log(record: dict) -> None:
            progress.reached(progress.TOKENIZER_STEPS, record["step"])  # a command's terminal bar
            for name in ("loss", "psnr", "lr"):
                writer.add_scalar(f"train/{name}", record[name], record["step"])
            if record["step"] % every == 0:  # about 20 progress lines per run, into the flow run's log
                print(f"step {record['step']}/{config.steps} ({record['seconds']:.0f} s): loss {record['loss']:.4f}, "
                      f"train PSNR {record['psnr']:.2f} dB")
        history = train_tokenizer(model, data.frame_arrays(clips), config, log, runtime)
    tokens.save_checkpoint(model, folder, {"train": config.model_dump(mode="json"), **extra})
    return history, sum(p.numel() for p in model.parameters())


def encode_shard(folder: Path, clips: list[data.Clip], target: Path, max_frames: int) -> tuple[str, int, int, float | None]:
    """Encode a shard's clips to a token shard; returns sha256, bytes, rows and the mean round-trip PSNR."""
    model = tokens.load_checkpoint(folder)
    rows, scores = [], []
    for clip in clips:
        row = tokens.encode_clip(model, clip, max_frames)
        if row is not None:
            rows.append(row)
            scores.append(psnr(to_tensor(clip.frames[:row["frames"]])[None], tokens.decode_row(model, row)).item())
    digest, size = tokens.write_token_shard(rows, target)
    return digest, size, len(rows), (sum(scores) / len(scores) if scores else None)
