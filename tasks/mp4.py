"""Write frames to an H.264 MP4 with PyAV, atomically and with reproducible bytes."""

from __future__ import annotations

import os
from collections.abc import Iterable
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

from tasks.curate.encode import EncodeConfig, x264_options


def write_mp4(path: Path, frames: Iterable[np.ndarray], fps: float, crf: int = 20, preset: str = "veryfast") -> Path:
    """frames: H x W x 3 uint8 RGB (even H and W). Same frames, same bytes: one x264 thread, and
    x264's AVX-512 code kept off (it reads memory it never wrote; see tasks/curate/encode.py)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.mp4")
    rate = Fraction(fps).limit_denominator(1001)
    try:
        with av.open(str(tmp), "w", options={"fflags": "+bitexact"}) as container:
            stream = None
            for image in frames:
                if stream is None:
                    stream = container.add_stream("libx264", rate=rate)
                    stream.height, stream.width = image.shape[:2]
                    stream.pix_fmt = "yuv420p"
                    stream.thread_count = 1
                    stream.options = {**x264_options(EncodeConfig(preset=preset, crf=crf)), "threads": "1"}
                    stream.codec_context.flags |= av.codec.context.Flags.bitexact
                for packet in stream.encode(av.VideoFrame.from_ndarray(image, format="rgb24")):
                    container.mux(packet)
            if stream is None:
                raise ValueError(f"{path}: no frames to write")
            for packet in stream.encode():
                container.mux(packet)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
