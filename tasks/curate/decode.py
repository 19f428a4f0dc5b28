"""Decode a source video once into small analysis frames.

Frame numbers everywhere in curation are the decoded-frame indices of ``tasks/video/read.py``
(frame ``i`` has the ``i``-th smallest packet pts), so a frame that fails to decode leaves a
gap instead of shifting every later index, and ``encode.py`` and ``exact.py`` can seek and
still find the same frames. Probing, opening and the packet index live in ``tasks.video``;
their names are importable from here too.
"""

from __future__ import annotations

import heapq
import queue
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import av
import cv2
import numpy as np
from av.video.reformatter import VideoReformatter
from pydantic import BaseModel, ConfigDict, Field

from tasks.video import DecodeError, SourceInfo, frame_pts, is_reference, nal_length_size, open_video, probe

__all__ = ["AnalysisConfig", "AnalysisFrame", "DecodeError", "DecodeReport", "SourceInfo", "analysis_frames",
           "analysis_size", "frame_pts", "is_reference", "nal_length_size", "open_video", "probe"]


class AnalysisConfig(BaseModel):
    """How the analysis pass decodes and downscales."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    long_side: int = Field(256, ge=16, le=4096, description="long side of analysis frames; never upscaled")
    # AHEAD: FFmpeg decodes on one thread, in a thread of its own that runs up to AHEAD_DEPTH
    # frames ahead of the analysis, so decoding and analysis overlap on two cores. FFmpeg's
    # frame threads (AUTO) spent 25% more CPU on the analysis pass for no shorter wall time
    # (a 2-minute 720p source: 11.3-11.5 s against 9.0-9.6 s of CPU, 2026-11-27). The curate
    # flow decodes each video on one thread (NONE) when every worker has one (`for_batch`).
    thread_type: Literal["AHEAD", "AUTO", "FRAME", "SLICE", "NONE"] = "AHEAD"
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
    # pixel check (``exact.frames_at``), and the scene splitter has the frames of a gap decoded exactly
    # (``exact.ExactFrames``) where the frames around it differ enough to hide a cut. It takes about
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


def analysis_size(info: SourceInfo, long_side: int) -> tuple[int, int]:
    """(width, height) of analysis frames in display orientation: long side at most ``long_side``."""
    dw, dh = info.display_width, info.display_height
    scale = min(1.0, long_side / max(dw, dh))
    return max(1, int(round(dw * scale))), max(1, int(round(dh * scale)))


def shrinker(info: SourceInfo, config: AnalysisConfig):
    """frame -> h x w x 3 uint8 RGB analysis image in display orientation."""
    aw, ah = analysis_size(info, config.long_side)
    turns = info.rotation // 90
    sw, sh = (ah, aw) if turns % 2 else (aw, ah)
    reformatter = VideoReformatter()

    def shrink(frame) -> np.ndarray:
        # libswscale's bgr24 output is both faster than its rgb24 (0.46 against 0.70 ms for
        # 720p to 256 px) and nearer a float BT.601 conversion (mean error 1.3 against 1.8
        # levels); cv2 swaps the channels back in microseconds. One thread: PyAV 18 slices the
        # scale over every core by default, which for a picture this small costs more in
        # hand-offs than it saves (0.74 against 2.2 ms a 720p frame on 2 busy cores, the
        # same pixels), and the curate flow already runs one video per core.
        small = reformatter.reformat(frame, sw, sh, "bgr24", interpolation=config.interpolation, threads=1)
        image = cv2.cvtColor(small.to_ndarray(), cv2.COLOR_BGR2RGB)
        return np.ascontiguousarray(np.rot90(image, k=turns)) if turns else image

    return shrink


def analysis_stream(container, config: AnalysisConfig):
    stream = container.streams.video[0]
    stream.thread_type = "NONE" if config.thread_type == "AHEAD" else config.thread_type
    stream.thread_count = config.threads
    if config.skip_loop_filter != "none":
        stream.codec_context.options = {"skip_loop_filter": config.skip_loop_filter}
    return stream


def _packets(container, stream, report: DecodeReport, path: Path) -> Iterator:
    try:
        yield from container.demux(stream)
    except av.FFmpegError as error:
        report.truncated = True
        report.problems.append(f"{path}: demux stopped early ({error.strerror or error})")


# Frames held back to put output pts in order (a packed B-frame swaps two neighbours).
REORDER_DEPTH = 2


AHEAD_DEPTH = 8  # analysis frames the decoding thread may run ahead (thread_type AHEAD)


def analysis_frames(
    path: Path | str,
    config: AnalysisConfig = AnalysisConfig(),
    report: DecodeReport | None = None,
    info: SourceInfo | None = None,
) -> Iterator[AnalysisFrame]:
    """Decode every frame once, downscaled in libswscale and rotated to display orientation.

    Yields AnalysisFrame(index, time, image) with image h x w x 3 uint8 RGB, h and w from
    ``analysis_size``. Memory is one frame plus the decoder's own buffers (and up to
    AHEAD_DEPTH frames with thread_type AHEAD). Packets the decoder rejects and frames it
    flags corrupt are skipped and counted in ``report``, complete once the iterator is.
    """
    frames = _analysis_frames(path, config, report, info)
    return ahead(frames, AHEAD_DEPTH) if config.thread_type == "AHEAD" else frames


_DONE = object()


def ahead(items: Iterator, depth: int) -> Iterator:
    """``items`` produced on a thread of its own, up to ``depth`` ahead of the consumer. What the
    producer raises is raised here, in order; closing this iterator early stops the producer."""
    waiting: queue.Queue = queue.Queue(depth)
    stop = threading.Event()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                waiting.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        try:
            for item in items:
                if not put((item, None)):
                    break
        except BaseException as exc:  # noqa: BLE001 (handed to the consumer, raised there)
            put((_DONE, exc))
            return
        finally:
            if stop.is_set():
                items.close()  # the consumer left early: the generator's own cleanup, on its thread
        put((_DONE, None))

    def consume() -> Iterator:
        worker = threading.Thread(target=produce, name="analysis-decode", daemon=True)
        worker.start()
        try:
            while True:
                item, error = waiting.get()
                if item is _DONE:
                    if error is not None:
                        raise error
                    return
                yield item
        finally:
            stop.set()
            worker.join()

    return consume()


def _analysis_frames(
    path: Path | str,
    config: AnalysisConfig,
    report: DecodeReport | None,
    info: SourceInfo | None,
) -> Iterator[AnalysisFrame]:
    path = Path(path)
    info = info or probe(path)
    report = report if report is not None else DecodeReport()
    shrink = shrinker(info, config)
    container = open_video(path)
    try:
        stream = analysis_stream(container, config)
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

