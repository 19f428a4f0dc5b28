"""Shared fixtures for the stage tests (curate, video): tiny H.264 MP4s written on the fly with PyAV.

``make_video(frames, fps=25.0, times=None, rotation=0, sar=None, crf=12, gop=None, name=None)``
writes ``frames`` (a sequence or generator of H x W x 3 uint8 RGB arrays, all the same
size) to a fresh MP4 under a session temp folder and returns its Path:

- ``fps``: nominal frame rate; frame ``i`` is shown at ``i / fps`` seconds unless ``times``
  is given.
- ``times``: per-frame presentation times in seconds (strictly increasing) for variable
  frame rate; stored at millisecond precision (time base 1/1000).
- ``rotation``: counter-clockwise degrees written as the container's display matrix (what
  phones write); the pixels stay as given, a player shows them rotated.
- ``sar``: sample aspect ratio (e.g. ``(4, 3)``) for non-square pixels.
- odd widths or heights are written as 4:4:4 H.264, which allows them; even sizes as yuv420p.
- ``crf``: x264 quality (0 is lossless in YUV); B-frames are on, as in real footage.
- ``gop``: a key frame every ``gop`` frames exactly (default: x264's own choice, which puts
  one at scene changes and at most every 250 frames).
- ``name``: file name inside the session folder (default: a fresh numbered name).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Sequence
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import pytest


def write_video(
    path: Path,
    frames: Iterable[np.ndarray],
    fps: float = 25.0,
    times: Sequence[float] | None = None,
    rotation: int = 0,
    sar: tuple[int, int] | None = None,
    crf: int = 12,
    gop: int | None = None,
) -> Path:
    iterator = iter(frames)
    first = next(iterator)
    h, w = first.shape[:2]
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
        stream.width, stream.height = w, h
        stream.pix_fmt = "yuv420p" if w % 2 == 0 and h % 2 == 0 else "yuv444p"
        stream.options = {"preset": "veryfast", "crf": str(crf)}
        if gop is not None:
            stream.options = {**stream.options, "x264-params": f"keyint={gop}:min-keyint={gop}:scenecut=0"}
        if times is not None:
            stream.codec_context.time_base = Fraction(1, 1000)
        if sar is not None:
            stream.codec_context.sample_aspect_ratio = Fraction(*sar)
        if rotation:
            stream.set_display_rotation(rotation)
        for i, image in enumerate(itertools.chain([first], iterator)):
            if image.shape != first.shape or image.dtype != np.uint8:
                raise ValueError(f"frame {i}: {image.shape} {image.dtype}, expected {first.shape} uint8")
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="rgb24")
            if times is not None:
                frame.pts = int(round(times[i] * 1000))
                frame.time_base = Fraction(1, 1000)
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return path


@pytest.fixture(scope="session")
def make_video(tmp_path_factory):
    """Factory: ``make_video(frames, **options) -> Path`` (see the module docstring)."""
    folder = tmp_path_factory.mktemp("videos")
    counter = itertools.count()

    def make(frames, fps=25.0, times=None, rotation=0, sar=None, crf=12, gop=None, name=None) -> Path:
        path = folder / (name or f"video_{next(counter):04d}.mp4")
        return write_video(path, frames, fps=fps, times=times, rotation=rotation, sar=sar, crf=crf, gop=gop)

    return make
