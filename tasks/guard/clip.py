"""guard_clip: re-encode an MP4 with every face hidden (the post-guard over a file)."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from schemas.hashing import sha256_file
from tasks import progress
from tasks.guard.config import GuardConfig
from tasks.guard.faces import FaceDecision, guard_stream, hide
from tasks.video import EncodeConfig, display_frames, probe, write_mp4


@dataclass(frozen=True, slots=True)
class GuardedClip:
    """The written clip and every face decision taken on it (frame indices are decoded order)."""

    path: Path
    sha256: str
    bytes: int
    frames: int
    width: int
    height: int
    decisions: tuple[FaceDecision, ...]


def guard_clip(path_in: Path | str, path_out: Path | str, config: GuardConfig = GuardConfig(),
               encode: EncodeConfig = EncodeConfig(),
               decisions_found: tuple[FaceDecision, ...] | None = None) -> GuardedClip:
    """Write ``path_in`` to ``path_out`` as H.264 (``encode``'s preset and crf, x264 as in
    ``tasks/video/write.py``: same input, same bytes) with every face hidden. With the guard off the
    file is copied unchanged. The output has the input's average frame rate (a variable-rate
    input comes out constant-rate) and no audio. ``decisions_found`` (what ``find_faces``
    returned for this file) hides those boxes without searching again."""
    path_in, path_out = Path(path_in), Path(path_out)
    if not config.enabled:
        path_out.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path_in, path_out)
        info = probe(path_out)
        return GuardedClip(path_out, sha256_file(str(path_out)), path_out.stat().st_size, info.n_frames,
                           info.display_width, info.display_height, ())
    info = probe(path_in)
    decisions: list[FaceDecision] = []
    shape: list[tuple[int, ...]] = []

    def stream() -> Iterator[tuple[np.ndarray, list[FaceDecision]]]:
        if decisions_found is None:
            yield from guard_stream(display_frames(path_in), config)
            return
        by_frame: dict[int, list[FaceDecision]] = {}
        for d in decisions_found:
            by_frame.setdefault(d.frame, []).append(d)
        for i, image in enumerate(display_frames(path_in)):
            made = by_frame.get(i, [])
            yield (hide(image, [d.box for d in made], config) if made else image), made

    def frames() -> Iterator[np.ndarray]:
        for image, made in stream():
            decisions.extend(made)
            shape.append(image.shape)
            yield image

    write_mp4(path_out, frames(), fps=info.fps, crf=encode.crf, preset=encode.preset)
    height, width = shape[0][:2]
    return GuardedClip(path_out, sha256_file(str(path_out)), path_out.stat().st_size, len(shape), width, height,
                       tuple(decisions))


def find_faces(path: Path | str, config: GuardConfig = GuardConfig()) -> tuple[FaceDecision, ...]:
    """Every face decision the guard would take on ``path``, without writing anything."""
    decisions: list[FaceDecision] = []
    for _, made in guard_stream(display_frames(Path(path)), config):
        decisions.extend(made)
    return tuple(decisions)


def guard_clips(paths: list[Path | str], config: GuardConfig = GuardConfig(),
                encode: EncodeConfig = EncodeConfig()) -> list[tuple[FaceDecision, ...]]:
    """The post-guard over encoded clips, in place: a clip with a face is re-encoded with every
    face hidden (temporary file, then rename); a clip without one is left byte for byte.

    Searching costs a decode (cheap) plus detection (what the guard costs anyway); only clips
    with faces pay a second encode. Returns each clip's decisions, in the order of ``paths``.
    """
    out = []
    for path in map(Path, paths):
        decisions = find_faces(path, config) if config.enabled else ()
        if decisions:
            tmp = path.with_name(f".{path.name}.guard.tmp.mp4")
            try:
                # The boxes just found are hidden as they are: detection, the costly part, runs once.
                decisions = guard_clip(path, tmp, config, encode, decisions_found=decisions).decisions
                os.replace(tmp, path)
            finally:
                tmp.unlink(missing_ok=True)
        out.append(decisions)
        progress.advance(progress.GUARDED)  # a command's terminal bar, when one listens in this process
    return out
