"""Checkpoints (safetensors + config JSON) and token shards (Parquet), and their lineage records.

Token shard rows (``TOKEN_SCHEMA``): the clip id and the shard it came from, the frames
encoded (the first ``1 + t k`` of the clip, at ``size x size``), the latent grid ``[T', H',
W']`` and either ``codes`` (discrete: int32 in [0, codebook), T' H' W' values in row-major
order) or ``latents`` (continuous: C T' H' W' bytes, value = byte / 127.5 - 1, the 8-bit
storage the bench counts). Files are written without timestamps, so the same model and clips
give the same bytes.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import torch

from models.tokenizer import TokenizerConfig, VideoTokenizer
from schemas import paths
from schemas.hashing import stable_id
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, MetricRecord
from tasks.checkpoint_files import CONFIG_FILE, WEIGHTS_FILE, load_weights, model_config, read_config, write_checkpoint
from tasks.tokenize.data import Clip, usable_frames
from tasks.tokenize.train import to_tensor

TOKEN_SCHEMA = pa.schema(
    [
        pa.field("clip_id", pa.string(), nullable=False),
        pa.field("source_shard", pa.string(), nullable=False),  # uri of the curated shard
        pa.field("variant", pa.string(), nullable=False),
        pa.field("frames", pa.int32(), nullable=False),
        pa.field("size", pa.int32(), nullable=False),
        pa.field("grid", pa.list_(pa.int32()), nullable=False),  # [T', H', W']
        pa.field("channels", pa.int32(), nullable=False),  # latent channels (continuous) or FSQ dims
        pa.field("codebook_size", pa.int64()),
        pa.field("codes", pa.list_(pa.int32())),
        pa.field("latents", pa.binary()),
    ],
    metadata={"worldline.token_schema": "1"},
)


def _sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def save_checkpoint(model: VideoTokenizer, folder: Path, extra: dict | None = None) -> tuple[Path, Path]:
    """Weights as safetensors and ``{"tokenizer": config, **extra}`` as JSON, each written atomically."""
    return write_checkpoint(model, folder, "tokenizer", extra)


def load_checkpoint(folder: Path) -> VideoTokenizer:
    """The tokenizer a checkpoint folder holds, in eval mode (CheckpointError naming the file otherwise)."""
    body = read_config(folder, "tokenizer", "tokenizer checkpoint")
    return load_weights(VideoTokenizer(model_config(TokenizerConfig, body, "tokenizer", folder)), folder)


@torch.no_grad()
def encode_clip(model: VideoTokenizer, clip: Clip, max_frames: int | None = None) -> dict | None:
    """One TOKEN_SCHEMA row, or None when the clip is shorter than one frame group's worth."""
    c = model.config
    n = usable_frames(clip.frames.shape[0], c.temporal_compression, max_frames)
    if n == 0:
        return None
    out = model.encode(to_tensor(clip.frames[:n])[None])[0]
    size = clip.frames.shape[1]
    row = {"clip_id": clip.clip_id, "source_shard": clip.shard_uri, "variant": c.variant, "frames": n,
           "size": size, "grid": list(c.latent_shape(n, size, size)), "channels": c.code_channels,
           "codebook_size": c.codebook_size if c.variant == "discrete" else None, "codes": None, "latents": None}
    if c.variant == "discrete":
        row["codes"] = out.flatten().to(torch.int32).tolist()
    else:
        row["latents"] = torch.round((out.clamp(-1, 1) + 1) * 127.5).to(torch.uint8).numpy().tobytes()
    return row


def decode_row(model: VideoTokenizer, row: dict) -> torch.Tensor:
    """A token shard row back to video ``1 x 3 x T x H x W`` in about [-1, 1]."""
    grid = tuple(row["grid"])
    if row["codes"] is not None:
        latents = torch.tensor(row["codes"], dtype=torch.int64).view(1, *grid)
    else:
        raw = np.frombuffer(row["latents"], dtype=np.uint8).reshape(row["channels"], *grid)
        latents = torch.from_numpy(raw.astype(np.float32) / 127.5 - 1)[None]
    with torch.no_grad():
        return model.decode(latents)


def write_token_shard(rows: Sequence[dict], path: Path) -> tuple[str, int]:
    """Write rows atomically; returns (sha256, bytes)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        pq.write_table(pa.Table.from_pylist(list(rows), schema=TOKEN_SCHEMA), tmp, compression="zstd",
                       write_statistics=False)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return _sha256(path), path.stat().st_size


def read_token_shard(path: Path) -> pa.Table:
    return pq.read_table(path, schema=TOKEN_SCHEMA)


def token_shard_path(root: Path, tokenizer_id: str, index: int) -> tuple[Path, str]:
    rel = paths.TOKEN_SHARD_FILE.format(tokenizer_id=tokenizer_id, index=index)
    return Path(root) / rel, Path(rel).as_posix()


def checkpoint_lineage(checkpoint_id: str, folder: Path, root: Path, shard_ids: Sequence[str],
                       history: Sequence[dict], stage_run_id: str, manifest_hash: str | None,
                       attrs: dict) -> LineageBatch:
    """The checkpoint artifact (its weights file), an edge from every shard it trained on
    ("trained_on"), and its loss and PSNR per logged step in the metrics table."""
    weights = folder / WEIGHTS_FILE
    batch = LineageBatch(artifacts=[ArtifactRecord(
        artifact_id=checkpoint_id, kind="checkpoint", uri=weights.relative_to(root).as_posix(),
        sha256=_sha256(weights), bytes=weights.stat().st_size, manifest_hash=manifest_hash,
        stage_run_id=stage_run_id, attrs={**attrs, "config_uri": (folder / CONFIG_FILE).relative_to(root).as_posix()},
    )])
    batch.edges.extend(EdgeRecord(parent_id=s, child_id=checkpoint_id, relation="trained_on") for s in shard_ids)
    for record in history:
        for name in ("loss", "psnr"):
            batch.metrics.append(MetricRecord(subject_id=checkpoint_id, name=f"train_{name}", step=record["step"],
                                              value=record[name], stage_run_id=stage_run_id,
                                              manifest_hash=manifest_hash))
    return batch


def token_shard_lineage(rel: str, sha256: str, size: int, n_rows: int, checkpoint_id: str, source_shard_id: str,
                        stage_run_id: str, manifest_hash: str | None, psnr: float | None) -> LineageBatch:
    """A token shard artifact with edges from its checkpoint ("encoded_by") and source shard ("tokens_of")."""
    token_id = stable_id("token_shard", rel, sha256)
    batch = LineageBatch(
        artifacts=[ArtifactRecord(artifact_id=token_id, kind="token_shard", uri=rel, sha256=sha256, bytes=size,
                                  manifest_hash=manifest_hash, stage_run_id=stage_run_id, attrs={"n_clips": n_rows})],
        edges=[EdgeRecord(parent_id=checkpoint_id, child_id=token_id, relation="encoded_by"),
               EdgeRecord(parent_id=source_shard_id, child_id=token_id, relation="tokens_of")],
    )
    if psnr is not None:
        batch.metrics.append(MetricRecord(subject_id=token_id, name="psnr", value=psnr, stage_run_id=stage_run_id,
                                          manifest_hash=manifest_hash))
    return batch
