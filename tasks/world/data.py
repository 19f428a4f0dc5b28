"""Code sequences for the world model: token shards (pre-training) and simulated episodes (post-training).

A ``CodeSequence`` is one video as latent codes ``T' x H' x W'`` int64 in [0, K) with its text
and, for an episode, its actions aligned to latent steps ``(T' - 1) x (t x action_dim)``
float32 (``align_actions``; layout in models/world_model.py). Token shards come from the
tokenize flow (tasks/tokenize/tokens.py ``TOKEN_SCHEMA``, discrete variant); their text is the
caption of the clip in the curated shard it came from. Episodes come from ``worldline
simulate`` (tasks/sim/files.py: an MP4 per camera, ``steps.parquet`` with ``time`` and
``action`` per control step, ``meta.json``): a camera's frames are decoded, squared to the
tokenizer's size, encoded, and the codes cached under ``schemas.paths.EPISODE_CODES_FILE``.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import torch

from models.tokenizer import VideoTokenizer
from schemas import paths
from schemas.errors import TamperedArtifact
from tasks.curate.shards import read_shard
from tasks.tokenize.data import find_shards, square, usable_frames
from tasks.tokenize.tokens import read_token_shard
from tasks.tokenize.train import to_tensor
from tasks.video import frame_rate, read_frames

# Frames are rendered at t = f / fps and actions start at t = k / control_hz; both are
# computed in floating point, so "the same instant" is decided to within this many seconds.
TIME_TOLERANCE_S = 1e-6


@dataclass(frozen=True)
class CodeSequence:
    """One video as codes ``T' x H' x W'`` int64, its text, and (episodes) actions
    ``(T' - 1) x action_features`` float32 whose row j leads from latent frame j to j + 1.
    ``info`` says where it came from (clip id and shard, or episode folder, camera, seed, ...)."""

    key: str
    codes: np.ndarray
    text: str
    actions: np.ndarray | None = None
    info: dict = field(default_factory=dict)

    @property
    def frames(self) -> int:
        return int(self.codes.shape[0])


# -- token shards (pre-training) -------------------------------------------------------------
def _captions(shard: Path) -> dict[str, str]:
    try:
        rows = read_shard(shard).select(["clip_id", "caption"]).to_pylist()
    except Exception:  # a moved or foreign source shard: the sequence trains without text
        return {}
    return {r["clip_id"]: r["caption"] for r in rows}


def load_token_sequences(files: Iterable[Path], root: Path) -> list[CodeSequence]:
    """Every discrete row of the token shards (files or folders) as a sequence; the caption
    comes from the row's source shard (``root``-relative), or is empty when that is gone."""
    out, captions = [], {}
    for path in find_shards(files):
        for row in read_token_shard(path).to_pylist():
            if row["codes"] is None:
                raise ValueError(f"{path}: continuous latents; the world model needs a discrete tokenizer's codes")
            source = row["source_shard"]
            if source not in captions:
                captions[source] = _captions(Path(root) / source)
            codes = np.asarray(row["codes"], dtype=np.int64).reshape(row["grid"])
            out.append(CodeSequence(key=row["clip_id"], codes=codes, text=captions[source].get(row["clip_id"], ""),
                                    info={"clip_id": row["clip_id"], "source_shard": source, "size": row["size"],
                                          "token_shard": str(path)}))
    return out


# -- simulated episodes (post-training) -----------------------------------------------------
def episode_dirs(place: Path) -> list[Path]:
    """Complete episode folders (meta.json is written last) under ``place``, or ``place`` itself."""
    place = Path(place)
    if (place / "meta.json").is_file():
        return [place]
    return sorted(p.parent for p in place.rglob("meta.json")) if place.is_dir() else []


def read_meta(directory: Path) -> dict:
    return json.loads((Path(directory) / "meta.json").read_text())


def read_steps(directory: Path) -> tuple[np.ndarray, np.ndarray]:
    """(time ``T`` s at the start of each control step, action ``T x A`` as applied)."""
    table = pq.read_table(Path(directory) / "steps.parquet", columns=["time", "action"])
    time = table.column("time").to_numpy().astype(np.float64)
    action = np.array(table.column("action").to_pylist(), dtype=np.float64).reshape(len(time), -1)
    return time, action


def align_actions(step_time: np.ndarray, action: np.ndarray, frame_time: np.ndarray, temporal_compression: int,
                  latent_frames: int, action_dim: int, totals: int = 0) -> np.ndarray:
    """Actions per latent step: ``(latent_frames - 1) x (temporal_compression x action_dim)`` float32.

    Control step k holds ``action[k]`` from ``step_time[k]``; it leads into the first frame
    rendered after that instant, ``f = min {f : frame_time[f] > step_time[k]}`` (a frame
    rendered at that very instant shows the state before the action). Latent frame j + 1
    covers video frames ``t j + 1 .. t j + t``, so row j has t slots, slot s the mean action
    (zero-padded to ``action_dim``) of the steps leading into frame ``t j + 1 + s``; a slot
    no step leads into stays zero, and steps leading past the last covered frame are dropped.

    With ``totals`` = n, each slot also holds, after the action's own values, the running sum
    of its first n values over every step up to that frame since the episode's first: for
    ``ee_delta`` actions (n = 3), the commanded tcp's offset from where it started. A model
    whose window holds a few latent frames cannot add up deltas from before it; the robot
    knows where it sent its hand (world models of robots condition on proprioception too).
    """
    t = temporal_compression
    if action.ndim != 2 or action.shape[0] != step_time.shape[0]:
        raise ValueError(f"action {action.shape} does not match {step_time.shape[0]} step times")
    if not 0 <= totals <= action.shape[1]:
        raise ValueError(f"totals {totals}: the actions have {action.shape[1]} values per step")
    if action.shape[1] + totals > action_dim:
        raise ValueError(f"actions have {action.shape[1]} values per step (+ {totals} totals); "
                         f"the model takes at most {action_dim}")
    out = np.zeros((max(latent_frames - 1, 0), t, action_dim), np.float64)
    counts = np.zeros(out.shape[:2], np.int64)
    frame = np.searchsorted(frame_time, step_time + TIME_TOLERANCE_S, side="right")
    for k, f in enumerate(frame):
        j, s = divmod(int(f) - 1, t)
        if f >= 1 and j < out.shape[0]:
            out[j, s, :action.shape[1]] += action[k]
            counts[j, s] += 1
    out /= np.maximum(counts, 1)[..., None]
    if totals:
        running = np.vstack([np.zeros((1, totals)), np.cumsum(action[:, :totals], axis=0)])
        slot_frame = 1 + np.arange(out.shape[0] * t)
        through = np.searchsorted(frame, slot_frame, side="right")  # steps leading into frames <= f
        out[:, :, action.shape[1]:action.shape[1] + totals] = running[through].reshape(out.shape[0], t, totals)
    return out.reshape(out.shape[0], t * action_dim).astype(np.float32)


def episode_text(instruction: str, stressors: Iterable[str]) -> str:
    """The conditioning text of an episode: the task instruction and its stressor kinds."""
    kinds = sorted(set(stressors))
    return instruction + (f"; stressors: {', '.join(kinds)}" if kinds else "")


@torch.no_grad()
def encode_frames(tokenizer: VideoTokenizer, frames: np.ndarray, size: int, max_frames: int | None = None) -> np.ndarray:
    """``T x H x W x 3`` uint8 -> codes ``T' x size/s x size/s`` int64 of the first ``1 + t k`` frames."""
    c = tokenizer.config
    if c.variant != "discrete":
        raise ValueError("the world model needs a discrete tokenizer")
    n = usable_frames(frames.shape[0], c.temporal_compression, max_frames)
    if n == 0:
        raise ValueError("no frames to encode")
    return tokenizer.eval().encode(to_tensor(square(frames[:n], size))[None])[0].numpy().astype(np.int64)


def _sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def cached_encoding(video: Path, encode, tokenizer_id: str, size: int, cache_root: Path | None,
                    pattern: str = paths.EPISODE_CODES_FILE, field: str = "codes",
                    stored=np.int32, loaded=np.int64) -> tuple[np.ndarray, float]:
    """(``encode(frames)``, fps) of one camera video, from the cache file ``pattern`` (under
    ``cache_root``, keyed by the tokenizer id, the video's sha256 and ``size``) when it holds them."""
    target = None
    if cache_root is not None and tokenizer_id:
        target = paths.resolve(cache_root, pattern, tokenizer_id=tokenizer_id, video_sha256=_sha256(video), size=size)
        if target.is_file():
            with np.load(target) as cached:
                return cached[field].astype(loaded), float(cached["fps"])
    values, fps = encode(read_frames(video)), frame_rate(video)
    if target is not None:
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
        with open(tmp, "wb") as fh:
            np.savez(fh, **{field: values.astype(stored)}, fps=np.float64(fps))
        os.replace(tmp, target)
    return values.astype(loaded), fps


def _cached_codes(video: Path, tokenizer: VideoTokenizer, tokenizer_id: str, size: int,
                  cache_root: Path | None) -> tuple[np.ndarray, float]:
    """(codes, fps) of one camera video, from the cache when it holds them."""
    return cached_encoding(video, lambda frames: encode_frames(tokenizer, frames, size), tokenizer_id, size, cache_root)


def episode_parts(directory: Path, camera: str, temporal_compression: int, encoded, action_dim: int = 8,
                  text: str | None = None, totals: int = 0) -> tuple[str, np.ndarray, str, np.ndarray, dict]:
    """(key, encoded video, text, aligned actions, info) of one camera of one episode, the video
    encoded by ``encoded(video path) -> (T' x ..., fps)``: ``load_episode`` without the type."""
    directory = Path(directory)
    meta = read_meta(directory)
    video = directory / f"{camera}.mp4"
    if not video.is_file():
        if camera in meta.get("cameras", []):  # simulate wrote it: gone since, behind lineage's back
            raise TamperedArtifact(f"{video}: missing, though the episode was recorded with it; run `worldline verify`")
        raise FileNotFoundError(f"{directory}: no camera {camera!r} (has {', '.join(meta.get('cameras', []))})")
    values, fps = encoded(video)
    step_time, action = read_steps(directory)
    t = temporal_compression
    frames = 1 + (values.shape[0] - 1) * t
    actions = align_actions(step_time, action, np.arange(frames) / fps, t, values.shape[0], action_dim, totals)
    if text is None:
        text = episode_text(meta.get("task", ""), meta.get("stressors", {}))
    info = {"episode": str(directory), "camera": camera, "index": meta.get("index"), "seed": meta.get("seed"),
            "success": meta.get("success"), "reason": meta.get("reason"), "fps": fps,
            "control_steps": int(step_time.shape[0]), "frames": frames, "manifest_hash": meta.get("manifest_hash")}
    return f"{directory.name}/{camera}", values, text, actions, info


def load_episode(directory: Path, camera: str, tokenizer: VideoTokenizer, size: int, action_dim: int = 8,
                 text: str | None = None, tokenizer_id: str = "", cache_root: Path | None = None,
                 totals: int = 0) -> CodeSequence:
    """One camera of one simulated episode as a ``CodeSequence`` with aligned actions.

    Its ``codes[:c]`` and ``actions[None, :c - 1 + n]`` are what ``WorldModel.rollout`` takes to
    predict ``codes[c:c + n]``.

    ``size``: frames are centre-cropped and resized to ``size x size`` before encoding: use the
    size of the tokenizer's token shards (the train flow writes it as ``size`` into the world
    model checkpoint's config.json, beside ``tokenizer``, the tokenizer's folder).
    ``action_dim``, ``totals``: the world model's ``config.action_dim`` and ``config.action_totals``.
    ``text`` defaults to the episode's
    task kind and stressor kinds from meta.json (pass ``episode_text(instruction, kinds)`` when
    the manifest is at hand). With ``cache_root`` (the data root) and a ``tokenizer_id``, codes
    are kept under ``EPISODE_CODES_FILE``, keyed by the tokenizer, the video's sha256 and size.
    ``info``: episode folder, camera, index, seed, success, reason, fps, control steps,
    manifest hash and ``frames`` (the video frames encoded: ``1 + t (T' - 1)``).
    """
    key, codes, text, actions, info = episode_parts(
        directory, camera, tokenizer.config.temporal_compression,
        lambda video: _cached_codes(video, tokenizer, tokenizer_id, size, cache_root), action_dim, text, totals)
    return CodeSequence(key=key, codes=codes, text=text, actions=actions, info=info)


def load_episodes(directories: Sequence[Path], tokenizer: VideoTokenizer, size: int, cameras: Sequence[str] | None = None,
                  action_dim: int = 8, text: str | None = None, tokenizer_id: str = "",
                  cache_root: Path | None = None, totals: int = 0) -> list[CodeSequence]:
    """``load_episode`` for every camera (or the ``cameras`` named) of every episode folder."""
    out = []
    for directory in directories:
        for camera in cameras or read_meta(directory).get("cameras", []):
            out.append(load_episode(directory, camera, tokenizer, size, action_dim, text, tokenizer_id, cache_root,
                                    totals))
    return out
