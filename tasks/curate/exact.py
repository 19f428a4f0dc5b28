"""Decode chosen frames exactly as a full decode gives them, even frames the analysis pass
leaves undecoded (``AnalysisConfig.skip_unreferenced``): the scene splitter asks for the
frames of a gap where a cut may hide, and dedup for the frames it compares pixel by pixel.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import av
import numpy as np

from tasks.curate.decode import AnalysisConfig, analysis_stream, shrinker
from tasks.video import SourceInfo, frame_pts, is_reference, nal_length_size, open_video, probe


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
        self.shrink = shrinker(info, config)
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
            self.stream = analysis_stream(self.container, self.config)
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
