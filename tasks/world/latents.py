"""Latent sequences for the diffusion world model: a continuous tokenizer's token shards
(pre-training) and simulated episodes encoded with it (post-training).

The continuous twin of tasks/world/data.py: a ``LatentSequence`` (tasks/world/diffusion.py) holds
latents ``T' x C x H' x W'`` float32 where a ``CodeSequence`` holds codes. Token shard rows store
latents as 8-bit bytes ``C T' H' W'`` (tasks/tokenize/tokens.py), decoded here exactly as the
tokenizer's ``decode_row`` does: ``byte / 127.5 - 1``. Episodes are encoded at full precision and
cached under ``schemas.paths.EPISODE_LATENTS_FILE``, keyed by the tokenizer as the codes cache is.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from models.tokenizer import VideoTokenizer
from schemas import paths
from tasks.tokenize.data import find_shards
from tasks.tokenize.tokens import read_token_shard
from tasks.world import data
from tasks.world.diffusion import LatentSequence, encode_latents


def row_latents(row: dict) -> np.ndarray:
    """A continuous token shard row's latents ``T' x C x H' x W'`` float32 (``decode_row``'s values)."""
    raw = np.frombuffer(row["latents"], dtype=np.uint8).reshape(row["channels"], *row["grid"])
    return (raw.astype(np.float32) / 127.5 - 1).transpose(1, 0, 2, 3).copy()


def load_latent_sequences(files: Iterable[Path], root: Path) -> list[LatentSequence]:
    """Every continuous row of the token shards (files or folders) as a sequence; the caption
    comes from the row's source shard (``root``-relative), or is empty when that is gone."""
    out, captions = [], {}
    for path in find_shards(files):
        for row in read_token_shard(path).to_pylist():
            if row["latents"] is None:
                raise ValueError(f"{path}: discrete codes; the diffusion world model needs a continuous "
                                 "tokenizer's latents")
            source = row["source_shard"]
            if source not in captions:
                captions[source] = data._captions(Path(root) / source)
            out.append(LatentSequence(key=row["clip_id"], latents=row_latents(row),
                                      text=captions[source].get(row["clip_id"], ""),
                                      info={"clip_id": row["clip_id"], "source_shard": source, "size": row["size"],
                                            "token_shard": str(path)}))
    return out


def load_latent_episode(directory: Path, camera: str, tokenizer: VideoTokenizer, size: int, action_dim: int = 8,
                        text: str | None = None, tokenizer_id: str = "", cache_root: Path | None = None,
                        totals: int = 0) -> LatentSequence:
    """One camera of one simulated episode as a ``LatentSequence`` with aligned actions (the
    arguments and ``info`` of ``tasks.world.data.load_episode``); latents cached under
    ``EPISODE_LATENTS_FILE`` with ``cache_root`` and a ``tokenizer_id``."""
    def encoded(video: Path):
        return data.cached_encoding(video, lambda frames: encode_latents(tokenizer, frames, size), tokenizer_id, size,
                                    cache_root, paths.EPISODE_LATENTS_FILE, "latents", np.float32, np.float32)

    key, latents, text, actions, info = data.episode_parts(directory, camera, tokenizer.config.temporal_compression,
                                                           encoded, action_dim, text, totals)
    return LatentSequence(key=key, latents=latents, text=text, actions=actions, info=info)


def load_latent_episodes(directories: Sequence[Path], tokenizer: VideoTokenizer, size: int,
                         cameras: Sequence[str] | None = None, action_dim: int = 8, text: str | None = None,
                         tokenizer_id: str = "", cache_root: Path | None = None,
                         totals: int = 0) -> list[LatentSequence]:
    """``load_latent_episode`` for every camera (or the ``cameras`` named) of every episode folder."""
    return [load_latent_episode(directory, camera, tokenizer, size, action_dim, text, tokenizer_id, cache_root, totals)
            for directory in directories for camera in cameras or data.read_meta(directory).get("cameras", [])]
