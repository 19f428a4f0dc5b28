"""Read a video: open it, probe what it declares, index its packets, and decode it whole.

The one place curate, guard and the stages that check footage open video files with PyAV.
Frame numbers are 0-based decoded-frame indices in presentation order: frame ``i`` is the
frame with the ``i``-th smallest packet pts of the video stream (packets the demuxer marks as
discard, e.g. edit-list pre-roll, are not frames), so a frame that fails to decode leaves a
gap instead of shifting every later index, and a seek finds the same frames again.
"""

from __future__ import annotations

import io
from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path
from typing import Literal

import av
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from tasks import faults

MAX_SIDE = 16384
MAX_FPS = 1000.0
# Below this a header is broken, not slow: an MP4 whose mdhd time scale is 0 reads as 1/512 fps.
MIN_FPS = 0.1
PROBE_PACKETS = 240  # enough packets to see irregular timestamps and a decodable frame


class DecodeError(ValueError):
    """One line: the file and the problem."""


class SourceInfo(BaseModel):
    """What a video declares, checked for sanity. Sizes in pixels, times in seconds.

    ``width`` x ``height`` is the decoded frame size; ``display_width`` x ``display_height``
    is what a player shows: width stretched by the sample aspect ratio, then swapped when the
    rotation is 90 or 270 degrees. ``rotation`` is counter-clockwise degrees in {0, 90, 180,
    270} (the display matrix, as PyAV's ``VideoFrame.rotation`` reports it).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    path: Path
    n_frames: int = Field(ge=0, description="container's frame count, or duration x fps")
    fps: float = Field(gt=0, description="average frame rate")
    duration: float = Field(ge=0)
    width: int = Field(gt=0)
    height: int = Field(gt=0)
    display_width: int = Field(gt=0)
    display_height: int = Field(gt=0)
    rotation: Literal[0, 90, 180, 270] = 0
    sar: float = Field(1.0, gt=0, description="sample (pixel) aspect ratio, width / height")
    codec: str
    vfr: bool = False


def _rate(stream) -> Fraction | None:
    for rate in (stream.average_rate, stream.guessed_rate, stream.base_rate):
        if rate is not None and rate > 0:
            return Fraction(rate)
    return None


def open_video(path: Path | str):
    """An open PyAV input container with a video stream, or DecodeError naming the problem."""
    path = Path(path)
    if not path.exists():
        raise DecodeError(f"{path}: no such file")
    if not path.is_file():
        raise DecodeError(f"{path}: not a regular file")
    if path.stat().st_size == 0:
        raise DecodeError(f"{path}: empty file (0 bytes)")
    try:
        container = av.open(str(path))
    except av.FFmpegError as error:
        raise DecodeError(f"{path}: not a readable video ({error.strerror or error})") from None
    if not container.streams.video:
        container.close()
        raise DecodeError(f"{path}: no video stream")
    return container


def _irregular(pts: list[int]) -> bool:
    steps = np.diff(np.sort(np.asarray(pts, dtype=np.int64)))
    steps = steps[steps > 0]
    if steps.size < 2:
        return False
    median = float(np.median(steps))
    return bool(np.any(np.abs(steps - median) > 0.02 * median + 1))


def probe(path: Path | str) -> SourceInfo:
    """Read the header and the first packets; raise DecodeError naming the file and problem.

    Decodes at most one frame (to read the rotation and prove the stream decodes), so it is
    cheap enough to run before any heavy work.
    """
    path = Path(path)
    faults.point("decode")  # crash tests: a video starts decoding
    container = open_video(path)
    try:
        stream = container.streams.video[0]
        ctx = stream.codec_context
        width, height = int(ctx.width or 0), int(ctx.height or 0)
        if not (0 < width <= MAX_SIDE and 0 < height <= MAX_SIDE):
            why = " (FFmpeg refused the size the header declares, or it declares none)" if not width * height else ""
            raise DecodeError(f"{path}: absurd frame size {width}x{height}{why}")
        rate = _rate(stream)
        if rate is None or not MIN_FPS <= float(rate) <= MAX_FPS:
            raise DecodeError(f"{path}: absurd or missing frame rate {rate}")
        fps = float(rate)
        tb = stream.time_base
        if stream.duration is not None and tb is not None and stream.duration > 0:
            duration = float(stream.duration * tb)
        elif container.duration is not None and container.duration > 0:
            duration = container.duration / av.time_base
        else:
            duration = 0.0
        n_frames = int(stream.frames) if stream.frames > 0 else int(round(duration * fps))
        sar_value = stream.sample_aspect_ratio or ctx.sample_aspect_ratio
        sar = float(sar_value) if sar_value and sar_value > 0 else 1.0
        if not 0.1 <= sar <= 10.0:
            raise DecodeError(f"{path}: absurd sample aspect ratio {sar_value}")

        rotation, pts = None, []
        try:
            for packet in container.demux(stream):
                if packet.size == 0:
                    continue
                if packet.pts is not None and not packet.is_discard:
                    pts.append(packet.pts)
                if rotation is None:
                    try:
                        frames = packet.decode()
                    except av.FFmpegError:
                        frames = []
                    if frames:
                        rotation = int(round(frames[0].rotation / 90.0)) * 90 % 360
                if len(pts) >= PROBE_PACKETS and rotation is not None:
                    break
        except av.FFmpegError as error:
            if rotation is None:
                raise DecodeError(f"{path}: unreadable stream ({error.strerror or error})") from None
        if rotation is None and pts:  # a decoder holding back frames (B-frame delay) gives them up on flush
            try:
                frames = stream.codec_context.decode(None)
            except av.FFmpegError:
                frames = []
            if frames:
                rotation = int(round(frames[0].rotation / 90.0)) * 90 % 360
        if rotation is None:
            raise DecodeError(f"{path}: no decodable frame in the first {len(pts)} packets")
        # An average rate that disagrees with the container's base rate is how FFmpeg shows a
        # variable frame rate it saw over the whole file; irregular steps catch the rest.
        base = stream.base_rate
        vfr = _irregular(pts) or bool(base and abs(float(base) - fps) > 0.01 * fps)
        codec = ctx.name
    finally:
        container.close()

    display_w = max(1, int(round(width * sar)))
    display_h = height
    if rotation in (90, 270):
        display_w, display_h = display_h, display_w
    return SourceInfo(
        path=path, n_frames=n_frames, fps=fps, duration=duration, width=width, height=height,
        display_width=display_w, display_height=display_h, rotation=rotation, sar=sar,
        codec=codec, vfr=vfr,
    )


def output_size(info: SourceInfo) -> tuple[int, int]:
    """Even (width, height) of clips in display orientation."""
    return max(2, info.display_width // 2 * 2), max(2, info.display_height // 2 * 2)


def frame_pts(path: Path | str) -> tuple[np.ndarray, np.ndarray, Fraction, int]:
    """Demux without decoding: (pts per frame index, sorted int64; key-frame pts, sorted;
    stream time base; stream start pts). Raises DecodeError when packets carry no pts."""
    path = Path(path)
    container = open_video(path)
    pts, keys = [], []
    try:
        stream = container.streams.video[0]
        try:
            for packet in container.demux(stream):
                if packet.size == 0 or packet.is_discard:
                    continue
                if packet.pts is None:
                    raise DecodeError(f"{path}: packets without timestamps")
                pts.append(packet.pts)
                if packet.is_keyframe:
                    keys.append(packet.pts)
        except av.FFmpegError:
            pass  # a truncated tail: the frames before it are still indexed
        start = stream.start_time if stream.start_time is not None else (min(pts) if pts else 0)
        return np.sort(np.asarray(pts, np.int64)), np.sort(np.asarray(keys, np.int64)), stream.time_base, start
    finally:
        container.close()


def nal_length_size(stream) -> int | None:
    """Bytes of each NAL unit's length prefix when an H.264 stream is in avcC form (MP4, MKV),
    0 when it uses Annex B start codes, None for other codecs."""
    if stream.codec_context.name != "h264":
        return None
    extra = bytes(stream.codec_context.extradata or b"")
    return (extra[4] & 3) + 1 if len(extra) > 4 and extra[0] == 1 else 0


def is_reference(data, length_size: int) -> bool:
    """False only when every slice of an H.264 access unit has nal_ref_idc 0, so that no other
    frame predicts from it and it may be left undecoded (anything unparsable counts as a
    reference). ``length_size`` from ``nal_length_size``."""
    data = bytes(data)
    n, pos, slices = len(data), 0, 0
    while pos < n:
        if length_size:
            if pos + length_size > n:
                return True
            size = int.from_bytes(data[pos: pos + length_size], "big")
            start, pos = pos + length_size, pos + length_size + size
            if size <= 0 or pos > n:
                return True
        else:  # Annex B: the unit runs to the next 00 00 01 start code
            found = data.find(b"\x00\x00\x01", pos)
            if found < 0:
                break
            start = found + 3
            following = data.find(b"\x00\x00\x01", start)
            pos = n if following < 0 else following
            if start >= n:
                break
        header = data[start]
        if header & 0x1F in (1, 5):  # a coded slice (non-IDR, IDR)
            slices += 1
            if header & 0x60:
                return True
    return slices == 0


def display_frames(path: Path) -> Iterator[np.ndarray]:
    """Every frame, decoded in full: H x W x 3 uint8 RGB in display orientation with square pixels
    and even sides (``output_size``)."""
    info = probe(path)
    width, height = output_size(info)
    turns = info.rotation // 90
    if turns % 2:
        width, height = height, width  # decoded size before the rotation
    container = open_video(path)
    try:
        for frame in container.decode(video=0):
            image = frame.reformat(width, height, "rgb24", interpolation="AREA").to_ndarray()
            yield np.ascontiguousarray(np.rot90(image, k=turns)) if turns else image
    finally:
        container.close()


def stored_frames(source: bytes | str | Path, max_frames: int | None = None) -> Iterator[np.ndarray]:
    """The frames as they are stored (no rotation or pixel-aspect correction, unlike
    ``display_frames``): H x W x 3 uint8 RGB, of an MP4 given as a path or as its bytes; the
    first ``max_frames`` when given. For the project's own videos (episodes, clips, panels)."""
    handle = io.BytesIO(source) if isinstance(source, bytes) else str(source)
    with av.open(handle) as container:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        for count, frame in enumerate(container.decode(stream), 1):
            yield frame.to_ndarray(format="rgb24")
            if max_frames and count >= max_frames:
                return


def read_frames(source: bytes | str | Path, max_frames: int | None = None) -> np.ndarray:
    """``stored_frames`` stacked: T x H x W x 3 uint8; ValueError when there is none."""
    frames = list(stored_frames(source, max_frames))
    if not frames:
        raise ValueError("no video frames" if isinstance(source, bytes) else f"{source}: no frames")
    return np.stack(frames)


def frame_rate(path: str | Path) -> float:
    """The video stream's average frame rate, as the container declares it."""
    with av.open(str(path)) as container:
        return float(container.streams.video[0].average_rate)
