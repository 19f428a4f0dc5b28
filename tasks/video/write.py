"""Write video: the x264 settings every H.264 file of the project is written with, and
``write_mp4`` for frames held in memory (simulated episodes, corpus footage, panels, guarded
clips). Curation's clip encoder (``tasks/curate/encode.py``) uses the same settings.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from fractions import Fraction
from pathlib import Path
from typing import Literal

import av
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from tasks.video import x264


class EncodeConfig(BaseModel):
    """x264 settings for clips."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    preset: Literal["ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow"] = "veryfast"
    crf: int = Field(23, ge=0, le=51)
    threads: int = Field(1, ge=1, le=16, description="x264 threads; fixed, since the bytes depend on it")
    x264_params: str = Field("", description="extra x264 options, e.g. 'keyint=60'")
    decode_threads: int = Field(0, ge=0, le=64, description="decoder threads (0: FFmpeg chooses)")
    decode_thread_type: Literal["AUTO", "NONE"] = Field("AUTO", description="NONE: decode on one thread")
    # x264's AVX-512 functions read memory they never wrote: on an AVX-512 CPU the same
    # frames gave 8 different clips in 8 runs (64x48) while x264 limited to AVX2 gave one.
    # The limit costs about a quarter of x264's speed on such CPUs (49 vs 67 fps at 720p).
    reproducible: bool = Field(True, description="keep x264 off AVX-512 so clips are byte-identical")

    @field_validator("x264_params")
    @classmethod
    def _x264_reads_it(cls, text: str) -> str:
        return x264.check(text)  # libx264 itself only warns and drops what it cannot read


# x264's names for the instruction sets below AVX-512, and the /proc/cpuinfo flag of each.
X264_CPU_NAMES = (("MMX2", "sse"), ("SSE2", "sse2"), ("SSE3", "pni"), ("SSSE3", "ssse3"), ("SSE4", "sse4_1"),
                  ("SSE4.2", "sse4_2"), ("AVX", "avx"), ("FMA3", "fma"), ("BMI1", "bmi1"), ("BMI2", "bmi2"),
                  ("AVX2", "avx2"), ("LZCNT", "abm"), ("Cache64", "clflush"))


def x264_cpu_limit(cpuinfo: str | None = None) -> str | None:
    """x264's ``asm=`` value that keeps this CPU's instruction sets but AVX-512, or None
    when there is nothing to limit (no AVX-512, or not a Linux x86 machine)."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            return None
    line = next((row for row in cpuinfo.splitlines() if row.startswith("flags")), "")
    flags = set(line.partition(":")[2].split())
    if "avx512f" not in flags:
        return None
    return ",".join(name for name, flag in X264_CPU_NAMES if flag in flags)


def x264_options(config: EncodeConfig) -> dict[str, str]:
    """The encoder options clips are written with (a benchmark baseline should use them too)."""
    params = [config.x264_params] if config.x264_params else []
    limit = x264_cpu_limit() if config.reproducible else None
    if limit:
        params.append(f"asm={limit}")
    options = {"preset": config.preset, "crf": str(config.crf)}
    if params:
        options["x264-params"] = ":".join(params)
    return options


def write_mp4(path: Path, frames: Iterable[np.ndarray], fps: float, crf: int = 20, preset: str = "veryfast") -> Path:
    """frames: H x W x 3 uint8 RGB (even H and W). Same frames, same bytes: one x264 thread, and
    x264's AVX-512 code kept off (it reads memory it never wrote; see EncodeConfig)."""
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
