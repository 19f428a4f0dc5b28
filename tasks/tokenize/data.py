"""Clips from curated shards, decoded with PyAV to square uint8 frames for the tokenizer.

A shard row (tasks/curate/shards.py ``SHARD_SCHEMA``) holds the clip's H.264 MP4 in
``clip_bytes``, or only a ``clip_uri`` (relative to the data root) when shards were written
without embedded clips. Frames are centre-cropped to a square and resized (area averaging) to
``size x size``: the tokenizer's grid needs sides divisible by its spatial compression.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from tasks.curate.shards import read_shard
from tasks.video import read_frames


@dataclass(frozen=True)
class Clip:
    """One decoded clip: ``frames`` is T x size x size x 3 uint8 RGB."""

    clip_id: str
    shard_uri: str
    frames: np.ndarray


def square(frames: np.ndarray, size: int) -> np.ndarray:
    """``T x H x W x 3`` uint8 -> centre square crop resized to ``T x size x size x 3`` uint8."""
    _, h, w, _ = frames.shape
    side = min(h, w)
    top, left = (h - side) // 2, (w - side) // 2
    crop = frames[:, top:top + side, left:left + side]
    if side == size:
        return np.ascontiguousarray(crop)
    x = torch.from_numpy(np.ascontiguousarray(crop)).permute(0, 3, 1, 2).float()
    mode = "area" if side > size else "bilinear"
    y = F.interpolate(x, size=(size, size), mode=mode, **({} if mode == "area" else {"align_corners": False}))
    return y.round().clamp(0, 255).to(torch.uint8).permute(0, 2, 3, 1).numpy()


def shard_clips(shard: Path, root: Path, shard_uri: str, size: int, max_frames: int | None = None) -> list[Clip]:
    """Every clip of one shard file, decoded and squared to ``size``."""
    table = read_shard(shard).select(["clip_id", "clip_uri", "clip_bytes"]).to_pylist()
    clips = []
    for row in table:
        source = row["clip_bytes"] if row["clip_bytes"] is not None else Path(root) / row["clip_uri"]
        clips.append(Clip(row["clip_id"], shard_uri, square(read_frames(source, max_frames), size)))
    return clips


def find_shards(locations: Iterable[Path]) -> list[Path]:
    """Parquet files under the given folders (or the files themselves), sorted, without repeats."""
    found: set[Path] = set()
    for place in locations:
        place = Path(place)
        found.update(place.rglob("*.parquet") if place.is_dir() else [place])
    return sorted(p.resolve() for p in found if p.is_file())


def usable_frames(n: int, temporal_compression: int, limit: int | None = None) -> int:
    """The most frames of the form 1 + t k that fit in ``n`` (and ``limit``); 0 if none."""
    n = min(n, limit) if limit else n
    return 0 if n < 1 else 1 + (n - 1) // temporal_compression * temporal_compression


def unique_clips(clips: Iterable[Clip]) -> list[Clip]:
    """The first clip of each clip id, in order. Shards are named by content (issue 26), so two
    curate runs over overlapping inputs leave one clip in two shards of a bucket; a reader of
    the folder takes it once."""
    seen: set[str] = set()
    return [c for c in clips if not (c.clip_id in seen or seen.add(c.clip_id))]


def frame_arrays(clips: Sequence[Clip]) -> list[np.ndarray]:
    """The frames of each clip id once (``unique_clips``): a clip in two shards trains once."""
    return [c.frames for c in unique_clips(clips)]
