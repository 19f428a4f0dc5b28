"""Probe a source video and decode it once into small analysis frames.

Frame numbers everywhere in curation are 0-based decoded-frame indices in presentation
order: frame ``i`` is the frame with the ``i``-th smallest packet pts of the video stream
(packets the demuxer marks as discard, e.g. edit-list pre-roll, are not frames). The index
comes from the packet timestamps, not from a counter, so a frame that fails to decode
leaves a gap instead of shifting every later index, and ``encode.py`` can seek and still
find the same frames.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterator
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Literal

import av
import cv2
import numpy as np
from av.video.reformatter import VideoReformatter
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


class AnalysisConfig(BaseModel):
    """How the analysis pass decodes and downscales."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    long_side: int = Field(256, ge=16, le=4096, description="long side of analysis frames; never upscaled")
    thread_type: Literal["AUTO", "FRAME", "SLICE", "NONE"] = "AUTO"
    threads: int = Field(0, ge=0, le=64, description="decoder threads; 0 lets FFmpeg choose")
    interpolation: Literal["AREA", "BILINEAR", "FAST_BILINEAR", "BICUBIC"] = "AREA"
    # H.264 deblocking is about a sixth of decode time. Skipped on every frame ("all"), its
    # error drifts through each group of pictures: a softly encoded copy of a clip came out
    # blocky enough to fail dedup's pixel check (residual 14.5 against 4.0 fully decoded).
    # Skipped on frames no other frame predicts from ("noref", most B-frames) it cannot drift,
    # and it still saves two thirds of the deblocking time (2.04 against 2.29 ms per 720p
    # frame on one thread; "all" 1.93). Clips are always encoded from fully decoded frames.
    skip_loop_filter: Literal["none", "noref", "all"] = "noref"
    # H.264 frames that no other frame predicts from (nal_ref_idc 0: most B-frames) need not
    # be decoded at all: their packets never reach the decoder. On x264 output that is 40 to
    # 54% of the frames, and no two decoded frames were more than 2 apart in any video we
    # have. What reads the stream knows: the scene splitter fills in rows for the frames left
    # out and scales the cut detector's ratio by the gap, a cut inside a gap leaves its frames
    # to neither scene, and dedup decodes the frames it samples exactly when a pair needs the
    # pixel check (``frames_at``), and the scene splitter has the frames of a gap decoded exactly
    # (``ExactFrames``) where the frames around it differ enough to hide a cut. It takes about
    # 0.8 ms a 720p source frame off the analysis.
    skip_unreferenced: bool = True


@dataclass(frozen=True, slots=True)
class AnalysisFrame:
    """One decoded frame: ``image`` is h x w x 3 uint8 RGB in display orientation."""

    index: int
    time: float  # seconds since the stream start, from the frame's pts
    image: np.ndarray


@dataclass(slots=True)
class DecodeReport:
    """Filled in while ``analysis_frames`` runs; read it after the iterator is exhausted."""

    frames: int = 0  # frames yielded
    decode_errors: int = 0  # packets the decoder refused
    corrupt: int = 0  # frames the decoder flagged corrupt (skipped)
    missing: int = 0  # indices that never came out of the decoder (gaps)
    unreferenced: int = 0  # frames not decoded on purpose (``skip_unreferenced``)
    truncated: bool = False  # the demuxer stopped on an error before the end
    problems: list[str] = field(default_factory=list)
    smeared: list[int] = field(default_factory=list)  # frames decoded but smeared by concealment (scenes)

    @property
    def skipped(self) -> int:
        return self.corrupt + self.missing


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


def analysis_size(info: SourceInfo, long_side: int) -> tuple[int, int]:
    """(width, height) of analysis frames in display orientation: long side at most ``long_side``."""
    dw, dh = info.display_width, info.display_height
    scale = min(1.0, long_side / max(dw, dh))
    return max(1, int(round(dw * scale))), max(1, int(round(dh * scale)))


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


def _shrinker(info: SourceInfo, config: AnalysisConfig):
    """frame -> h x w x 3 uint8 RGB analysis image in display orientation."""
    aw, ah = analysis_size(info, config.long_side)
    turns = info.rotation // 90
    sw, sh = (ah, aw) if turns % 2 else (aw, ah)
    reformatter = VideoReformatter()

    def shrink(frame) -> np.ndarray:
        # libswscale's bgr24 output is both faster than its rgb24 (0.46 against 0.70 ms for
        # 720p to 256 px) and nearer a float BT.601 conversion (mean error 1.3 against 1.8
        # levels); cv2 swaps the channels back in microseconds.
        small = reformatter.reformat(frame, sw, sh, "bgr24", interpolation=config.interpolation)
        image = cv2.cvtColor(small.to_ndarray(), cv2.COLOR_BGR2RGB)
        return np.ascontiguousarray(np.rot90(image, k=turns)) if turns else image

    return shrink


def _analysis_stream(container, config: AnalysisConfig):
    stream = container.streams.video[0]
    stream.thread_type = config.thread_type
    stream.thread_count = config.threads
    if config.skip_loop_filter != "none":
        stream.codec_context.options = {"skip_loop_filter": config.skip_loop_filter}
    return stream


class ExactFrames:
    """Analysis images of chosen frames, each exactly as a pass decoding every frame makes it,
    even a frame that pass leaves undecoded (``skip_unreferenced``). Keep one open while a
    stream is analysed: the packet index is read once and the container stays open, so asking
    for frames in increasing order decodes forward from where the last request stopped, or
    seeks to the key frame before a wanted frame when that skips a key frame.

    Decodes only what the wanted frames are predicted from (the reference frames) on the way.
    Frames that cannot be decoded are absent from the result. ``close()`` when done.
    """

    def __init__(self, path: Path | str, config: AnalysisConfig = AnalysisConfig(), info: SourceInfo | None = None):
        self.path = Path(path)
        info = info or probe(self.path)
        self.pts, self.keys, self.time_base, self.start = frame_pts(self.path)
        self.shrink = _shrinker(info, config)
        self.config = config
        self.container = None
        self.frames = None
        self.position = -1  # the last frame index decoded
        self.skipped: set[int] = set()  # pts of packets the open reader left undecoded

    def time(self, index: int) -> float:
        """Seconds since the stream start of frame ``index`` (as ``analysis_frames`` gives it)."""
        return float((int(self.pts[index]) - self.start) * self.time_base)

    def get(self, indices) -> dict[int, np.ndarray]:
        pts, keys = self.pts, self.keys
        remaining = sorted({int(i) for i in indices if 0 <= int(i) < len(pts)})
        wanted = {int(pts[i]) for i in remaining}
        out: dict[int, np.ndarray] = {}
        if self.container is None and remaining:
            self.container = open_video(self.path)
            self.stream = _analysis_stream(self.container, self.config)
            self.length_size = nal_length_size(self.stream)
        while remaining:
            target = remaining[0]
            key = int(np.searchsorted(keys, pts[target], side="right")) - 1
            key_index = int(np.searchsorted(pts, keys[key])) if key >= 0 else 0
            # Continue forward unless that skips a key frame, or the wanted frame was behind
            # us or already left undecoded (packets run ahead of frames by the reorder delay).
            if (self.frames is None or key_index > self.position + 1 or target <= self.position
                    or int(pts[target]) in self.skipped):
                if key_index > 0 or self.frames is not None:
                    try:
                        self.container.seek(int(pts[key_index]), stream=self.stream, backward=True)
                    except av.FFmpegError:
                        break  # what was decoded so far stands
                    self.stream.codec_context.flush_buffers()
                self.position = key_index - 1
                self.wanted, self.skipped = set(), set()
                self.frames = _frames_towards(self.container.demux(self.stream), self.stream, self.wanted,
                                              self.length_size, self.skipped)
            self.wanted.clear()
            self.wanted.update(wanted)  # what the open packet reader must not leave undecoded
            for frame in self.frames:
                index = int(np.searchsorted(pts, frame.pts)) if frame.pts is not None else -1
                if index < 0 or index >= len(pts) or pts[index] != frame.pts or index <= self.position:
                    continue  # pre-roll of a seek, or a frame the index does not know
                self.position = index
                if frame.pts in wanted and not frame.is_corrupt:
                    out[index] = self.shrink(frame)
                if self.position >= target:
                    break
            else:
                self.frames = None  # the stream ended
                break
            remaining = [i for i in remaining if i > self.position]
        return out

    def close(self) -> None:
        if self.container is not None:
            self.container.close()
            self.container = self.frames = None


def frames_at(path: Path | str, indices, config: AnalysisConfig = AnalysisConfig(),
              info: SourceInfo | None = None) -> dict[int, np.ndarray]:
    """Analysis images of the frames at ``indices`` (frame numbers as ``analysis_frames``
    counts them), each exactly as a pass decoding every frame makes it (see ``ExactFrames``)."""
    exact = ExactFrames(path, config, info)
    try:
        return exact.get(indices)
    finally:
        exact.close()


def _frames_towards(packets, stream, wanted: set[int], length_size: int | None,
                    skipped: set[int] | None = None) -> Iterator:
    """Decoded frames of the remaining ``packets``, leaving out unreferenced frames that are not
    ``wanted`` (by pts; their pts go to ``skipped``); the decoder is drained at the end."""
    try:
        for packet in packets:
            if packet.size == 0:
                continue
            if (length_size is not None and packet.pts not in wanted
                    and not is_reference(packet, length_size)):
                if skipped is not None and packet.pts is not None:
                    skipped.add(packet.pts)
                continue
            try:
                yield from packet.decode()
            except av.FFmpegError:
                continue
        yield from stream.decode(None)
    except av.FFmpegError:
        return


def _packets(container, stream, report: DecodeReport, path: Path) -> Iterator:
    try:
        yield from container.demux(stream)
    except av.FFmpegError as error:
        report.truncated = True
        report.problems.append(f"{path}: demux stopped early ({error.strerror or error})")


# Frames held back to put output pts in order (a packed B-frame swaps two neighbours).
REORDER_DEPTH = 2


def analysis_frames(
    path: Path | str,
    config: AnalysisConfig = AnalysisConfig(),
    report: DecodeReport | None = None,
    info: SourceInfo | None = None,
) -> Iterator[AnalysisFrame]:
    """Decode every frame once, downscaled in libswscale and rotated to display orientation.

    Yields AnalysisFrame(index, time, image) with image h x w x 3 uint8 RGB, h and w from
    ``analysis_size``. Memory is one frame plus the decoder's own buffers. Packets the decoder
    rejects and frames it flags corrupt are skipped and counted in ``report``.
    """
    path = Path(path)
    info = info or probe(path)
    report = report if report is not None else DecodeReport()
    shrink = _shrinker(info, config)
    container = open_video(path)
    try:
        stream = _analysis_stream(container, config)
        tb = stream.time_base
        start = stream.start_time or 0
        length_size = nal_length_size(stream) if config.skip_unreferenced else None
        unreferenced: set[int] = set()  # pts of packets left undecoded on purpose
        pending: list[int] = []  # pts demuxed but not yet decoded
        counted = 0  # frame indices handed out or found missing
        step = 1.0 / info.fps
        last_time: float | None = None

        # Frames wait in a short queue and leave it in the decoder's output order, each stamped
        # with the smallest pts among those waiting. The decoder's order is display order; its
        # pts normally agree, but MPEG-4 Part 2 in AVI with packed B-frames stamps output frames
        # 1, 2, 4, 3, 5, 7, 6, ...: read as they come, every swapped pair looked like a missing
        # frame plus a repeated one (makeup_webcam.avi: 54 "missing" and 54 "corrupt" of 164).
        held: list[tuple[object, bool, np.ndarray]] = []  # (pts, corrupt, image) in output order
        stamps: list[int] = []  # heap of the pts of the frames in `held`

        def emit(pts, corrupt: bool, image: np.ndarray) -> AnalysisFrame | None:
            nonlocal counted, last_time
            if pts is not None and pending and pending[0] <= pts:
                while pending and pending[0] < pts:
                    gone = heapq.heappop(pending)
                    counted += 1
                    if gone in unreferenced:
                        unreferenced.discard(gone)
                        report.unreferenced += 1
                    else:
                        report.missing += 1
                if pending and pending[0] == pts:
                    heapq.heappop(pending)
                time = float((pts - start) * tb)
            else:  # no usable pts: trust the decoder's order
                time = 0.0 if last_time is None else last_time + step
            index = counted
            counted += 1
            if corrupt or (last_time is not None and time <= last_time):  # or a repeated pts
                report.corrupt += 1
                return None
            last_time = time
            report.frames += 1
            return AnalysisFrame(index=index, time=time, image=image)

        def take(frame) -> None:
            held.append((frame.pts, bool(frame.is_corrupt), shrink(frame)))
            if frame.pts is not None:
                heapq.heappush(stamps, frame.pts)

        def release(keep: int) -> Iterator[AnalysisFrame]:
            while len(held) > keep:
                pts, corrupt, image = held.pop(0)
                item = emit(heapq.heappop(stamps) if pts is not None else None, corrupt, image)
                if item is not None:
                    yield item

        for packet in _packets(container, stream, report, path):
            if packet.size == 0:
                continue
            if packet.pts is not None and not packet.is_discard:
                heapq.heappush(pending, packet.pts)
                if length_size is not None and not is_reference(packet, length_size):
                    unreferenced.add(packet.pts)
                    continue
            try:
                frames = packet.decode()
            except av.FFmpegError:
                report.decode_errors += 1
                continue
            for frame in frames:
                take(frame)
            yield from release(REORDER_DEPTH)
        try:
            frames = stream.decode(None)
        except av.FFmpegError:
            frames = []
            report.decode_errors += 1
        for frame in frames:
            take(frame)
        yield from release(0)
        report.unreferenced += len(unreferenced)
        report.missing += len(pending) - len(unreferenced)
    finally:
        container.close()
    if report.frames == 0:
        raise DecodeError(f"{path}: no frame could be decoded")
    if report.decode_errors or report.skipped:
        report.problems.append(
            f"{path}: skipped {report.skipped} frames ({report.corrupt} corrupt, "
            f"{report.missing} missing; {report.decode_errors} packets rejected)"
        )

