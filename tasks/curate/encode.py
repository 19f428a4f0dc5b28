"""Re-encode spans of a source video to H.264 MP4 clips, all spans of a source in one pass.

Frame numbers are the decoded-frame indices of ``tasks/video/read.py`` (frame i has the i-th
smallest packet pts), so a span found by the analysis pass maps to exactly the same frames here even
after a seek. Clips are written in display orientation with square pixels and even sizes
(yuv420p needs them). With a fixed ``threads`` count x264 is deterministic, so the same
input and config give byte-identical clips; each clip is written to a temporary file and
renamed into place, so a crash never leaves a half-written clip under its final name.
``EncodeConfig`` and the x264 options are those of ``tasks/video/write.py``.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
from av.video.frame import PictureType
from pydantic import BaseModel, ConfigDict

from tasks import faults
from tasks.video import (
    DecodeError,
    EncodeConfig,
    SourceInfo,
    frame_pts,
    is_reference,
    nal_length_size,
    open_video,
    output_size,
    probe,
    x264_options,
)


class EncodedClip(BaseModel):
    """One written clip; ``frames`` counts the frames actually encoded."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    path: Path
    sha256: str
    bytes: int
    frames: int
    width: int
    height: int
    start_frame: int
    end_frame: int


class _Writer:
    """An open output clip: encoder, muxer and temporary path. On a full disk each step raises
    ``EnvironmentFault`` naming the clip (the run stops; the source video is not to blame)."""

    def __init__(self, out: Path, info: SourceInfo, src_stream, config: EncodeConfig):
        self.out = Path(out)
        self.tmp = self.out.with_name(f".{self.out.name}.{os.getpid()}.tmp")
        with faults.fatal_when_disk_full(self.tmp, "encoding clips"):
            self.out.parent.mkdir(parents=True, exist_ok=True)
            try:
                self.container = av.open(str(self.tmp), "w", format="mp4")
            except BaseException:
                self.tmp.unlink(missing_ok=True)
                raise
        self.width, self.height = output_size(info)
        self.stream = self.container.add_stream("libx264", rate=Fraction(info.fps).limit_denominator(1001))
        self.stream.width, self.stream.height, self.stream.pix_fmt = self.width, self.height, "yuv420p"
        self.stream.codec_context.time_base = src_stream.time_base
        self.stream.codec_context.thread_count = config.threads
        src = src_stream.codec_context
        for name in ("color_range", "colorspace", "color_primaries", "color_trc"):
            setattr(self.stream.codec_context, name, getattr(src, name))
        self.stream.options = x264_options(config)
        self.first_pts: int | None = None
        self.frames = 0

    def write(self, frame: av.VideoFrame) -> None:
        """Encode ``frame`` (shared between writers: its pts is restored afterwards)."""
        if self.first_pts is None:
            self.first_pts = frame.pts
        pts = frame.pts
        frame.pts = pts - self.first_pts
        frame.pict_type = PictureType.NONE  # else x264 copies the source's frame types
        try:
            with faults.fatal_when_disk_full(self.tmp, "encoding clips"):
                for packet in self.stream.encode(frame):
                    self.container.mux(packet)
        finally:
            frame.pts = pts
        self.frames += 1

    def close(self, start: int, end: int) -> EncodedClip:
        """Finish the clip and rename it into place; on any failure the temporary is removed."""
        try:
            with faults.fatal_when_disk_full(self.tmp, "encoding clips"):
                for packet in self.stream.encode():
                    self.container.mux(packet)
                self.container.close()
                if self.frames == 0:
                    raise DecodeError(f"{self.out}: no frame of the span [{start}, {end}) could be decoded")
                digest = hashlib.sha256()
                with open(self.tmp, "rb") as handle:
                    for block in iter(lambda: handle.read(1 << 20), b""):
                        digest.update(block)
                size = self.tmp.stat().st_size
                faults.point("clip", self.tmp)  # crash tests: a whole clip in its temporary file, not yet renamed
                os.replace(self.tmp, self.out)
        except BaseException:
            self.abort()
            raise
        return EncodedClip(path=self.out, sha256=digest.hexdigest(), bytes=size, frames=self.frames,
                           width=self.width, height=self.height, start_frame=start, end_frame=end)

    def abort(self) -> None:
        try:
            self.container.close()
        except (av.FFmpegError, OSError):  # a full disk again, or closed already
            pass
        self.tmp.unlink(missing_ok=True)


def _to_display(frame: av.VideoFrame, info: SourceInfo, size: tuple[int, int]) -> av.VideoFrame:
    """The frame as the encoder wants it: yuv420p, display orientation, even size."""
    turns = info.rotation // 90
    width, height = size if turns % 2 == 0 else size[::-1]
    if frame.format.name == "yuv420p" and (frame.width, frame.height) == (width, height) and not turns:
        return frame  # the common case costs nothing
    pts, time_base = frame.pts, frame.time_base
    if turns:
        rgb = frame.reformat(width, height, "rgb24").to_ndarray()
        out = av.VideoFrame.from_ndarray(np.ascontiguousarray(np.rot90(rgb, k=turns)), format="rgb24")
        out = out.reformat(format="yuv420p")
    else:
        out = frame.reformat(width, height, "yuv420p", interpolation="AREA")
    out.pts, out.time_base = pts, time_base
    return out


def encode_clips(source: Path | str, spans: Sequence[tuple[int, int]], out_paths: Sequence[Path | str],
                 config: EncodeConfig = EncodeConfig(), info: SourceInfo | None = None) -> list[EncodedClip]:
    """Encode each span [start_frame, end_frame) of ``source`` to its path, in one forward pass.

    Spans may come in any order and may overlap. Between spans the decoder seeks to the
    last key frame before the next span when that skips at least one key frame; otherwise it
    decodes through. On the way to a span (from the key frame, or through a gap) an H.264
    frame no other frame predicts from and no span holds is not decoded at all (``_idle``):
    the frames of the spans are the same, and about half of the lead-in is left out. Returns
    the clips in the order of ``spans``.
    """
    source = Path(source)
    if len(spans) != len(out_paths):
        raise ValueError(f"{source}: {len(spans)} spans but {len(out_paths)} output paths")
    info = info or probe(source)
    pts, keys, _, _ = frame_pts(source)
    for start, end in spans:
        if not 0 <= start < end <= len(pts):
            raise ValueError(f"{source}: span [{start}, {end}) outside frames [0, {len(pts)})")
    order = sorted(range(len(spans)), key=lambda j: spans[j])
    size = output_size(info)
    results: dict[int, EncodedClip] = {}
    writers: dict[int, _Writer] = {}
    container = open_video(source)
    frames = None
    try:
        stream = container.streams.video[0]
        stream.thread_type = config.decode_thread_type
        stream.thread_count = config.decode_threads
        idle = _idle(stream, pts, spans)
        waiting = list(order)  # spans not yet started, by start frame
        position = -1  # index of the last frame decoded
        while waiting or writers:
            if not writers:
                # Idle between spans: seek when a key frame lies between here and the next span.
                start = spans[waiting[0]][0]
                key = int(np.searchsorted(keys, pts[start], side="right")) - 1 if len(keys) else -1
                key_index = int(np.searchsorted(pts, keys[key])) if key >= 0 else 0
                if frames is None or key_index > position + 1:
                    if frames is not None:
                        frames.close()
                    if key_index > position + 1:
                        container.seek(int(keys[key]), stream=stream, backward=True)
                        position = key_index - 1
                    frames = _frames(container, stream, idle)
            frame = next(frames, None)
            if frame is None:
                break
            index = int(np.searchsorted(pts, frame.pts)) if frame.pts is not None else position + 1
            if index >= len(pts) or pts[index] != frame.pts or index <= position:
                continue  # pre-roll of a seek, or a frame the index does not know
            position = index
            while waiting and spans[waiting[0]][0] <= index:
                j = waiting.pop(0)
                writers[j] = _Writer(Path(out_paths[j]), info, stream, config)
            for j in [j for j in writers if spans[j][1] <= index]:
                results[j] = writers.pop(j).close(*spans[j])
            if writers:
                shown = _to_display(frame, info, size)
                for writer in writers.values():
                    writer.write(shown)
        for j in list(writers):
            results[j] = writers.pop(j).close(*spans[j])
        if waiting:
            raise DecodeError(f"{source}: span {spans[waiting[0]]} starts after the last decodable frame")
    except BaseException:
        for writer in writers.values():
            writer.abort()
        raise
    finally:
        if frames is not None:
            frames.close()
        container.close()
    return [results[j] for j in range(len(spans))]


def _idle(stream, pts: np.ndarray, spans: Sequence[tuple[int, int]]):
    """packet -> whether its frame may go undecoded: an H.264 frame that no other frame
    predicts from (``is_reference``) and that lies in none of ``spans``. None for other codecs."""
    length_size = nal_length_size(stream)
    if length_size is None:
        return None
    shown = np.zeros(len(pts), bool)
    for start, end in spans:
        shown[start:end] = True

    def idle(packet) -> bool:
        if packet.pts is None:
            return False
        index = int(np.searchsorted(pts, packet.pts))
        return index < len(pts) and pts[index] == packet.pts and not shown[index] \
            and not is_reference(packet, length_size)

    return idle


def _frames(container, stream, idle=None):
    try:
        for packet in container.demux(stream):
            if idle is not None and packet.size and idle(packet):
                continue  # nothing shows this frame or predicts from it
            try:
                yield from packet.decode()
            except av.FFmpegError:
                continue  # a corrupt packet: its frame is missing from the clip
    except av.FFmpegError:
        return  # a truncated tail ends the pass


def encode_clip(source: Path | str, start_frame: int, end_frame: int, out: Path | str,
                config: EncodeConfig = EncodeConfig(), info: SourceInfo | None = None) -> EncodedClip:
    """Encode frames [start_frame, end_frame) of ``source`` to ``out`` (see ``encode_clips``)."""
    return encode_clips(source, [(start_frame, end_frame)], [out], config, info)[0]
