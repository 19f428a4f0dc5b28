"""PySceneDetect's hard-cut detectors, fed the splitter's RGB frames.

The stock detectors take BGR frames and measure frame differences on int32 numpy copies; the
classes here take RGB (the analysis frames' order, so no BGR copy is made) and difference
uint8 planes in OpenCV. Scores are bit for bit the stock ones (the sums are exact integers
either way), and so are cuts when every frame is decoded: test_detectors checks both against
the stock detectors on real footage. Frames left undecoded change the adaptive ratio only
(``RgbAdaptiveDetector``).
"""

from __future__ import annotations

import cv2
import numpy as np
from scenedetect.common import FrameTimecode
from scenedetect.detectors import AdaptiveDetector, ContentDetector

GAP_POWER = 0.5  # a content score over g frames ~ g ** GAP_POWER times one over a frame (see RgbAdaptiveDetector)


class _RgbScore:
    """ContentDetector's frame score on RGB frames (PySceneDetect 0.7 with its default weights:
    hue, saturation and value; no edges and no stats manager, which the splitter never sets).
    A caller that has the frame's HSV already (the splitter compares it across undecoded gaps)
    hands it to ``process_frame`` and the frame is not converted again."""

    _hsv: np.ndarray | None = None  # the HSV of the frame being processed, when the caller had it

    def _calculate_frame_score(self, timecode: FrameTimecode, frame_img: np.ndarray) -> float:
        hsv, self._hsv = self._hsv, None
        hue, sat, lum = cv2.split(hsv if hsv is not None else cv2.cvtColor(frame_img, cv2.COLOR_RGB2HSV))
        last, self._last_frame = self._last_frame, ContentDetector._FrameData(hue, sat, lum, None)
        if last is None:
            return 0.0
        pixels = float(hue.shape[0] * hue.shape[1])
        planes = ((hue, last.hue), (sat, last.sat), (lum, last.lum))
        components = ContentDetector.Components(
            *(cv2.sumElems(cv2.absdiff(a, b))[0] / pixels for a, b in planes), delta_edges=0.0)
        return sum(c * w for c, w in zip(components, self._weights, strict=True)) / sum(abs(w) for w in self._weights)


class RgbAdaptiveDetector(_RgbScore, AdaptiveDetector):
    """AdaptiveDetector fed RGB frames (see ``_RgbScore``), knowing how far apart they are.

    The analysis pass leaves out frames nothing predicts from, so a frame's score may span
    two source frames while its neighbours' span one, or the other way round. The stock ratio
    (score over the mean of its neighbours' scores) then moves with the pattern of frame
    types: on bikes.mp4 the cut at frame 76 (gap 1, neighbours' gaps 2) fell from 3.2 to 2.35.
    Here each neighbour's score is scaled to the frame's own gap before the mean:
    ``score / mean(score_i * (gap / gap_i) ** GAP_POWER)``. Content scores grow slower than
    the gap (motion saturates the HSV difference), and the power was chosen on the tuning
    seeds 400-405 by replaying their scores: 1 (linear) let 14 more false cuts through, 0.5
    recovered 4 missed cuts and added none. With every gap 1 this is the stock ratio, to the bit.

    ``weak_threshold`` (below ``adaptive_threshold``) also collects, in ``weak``, the frames
    whose ratio reaches it but not the threshold (with the same floor and gap to the last
    cut): candidates the splitter may confirm on the pictures. None collects nothing.
    """

    def __init__(self, *args, weak_threshold: float | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.weak_threshold = weak_threshold
        self.weak: list[FrameTimecode] = []

    def process_frame(self, timecode: FrameTimecode, frame_img: np.ndarray, gap: int = 1,
                      hsv: np.ndarray | None = None) -> list[FrameTimecode]:
        """``hsv``: ``frame_img`` in OpenCV's RGB2HSV, when the caller has it."""
        self._hsv = hsv
        ContentDetector.process_frame(self, timecode=timecode, frame_img=frame_img)
        if self._frame_score is None:
            return []
        if self._last_cut is None:
            self._last_cut = timecode
        required = 1 + 2 * self.window_width
        self._buffer.append((timecode, self._frame_score, max(1, gap)))
        if len(self._buffer) < required:
            return []
        self._buffer = self._buffer[-required:]
        target_timecode, target_score, target_gap = self._buffer[self.window_width]
        average = sum(score if g == target_gap else score * (target_gap / g) ** GAP_POWER
                      for i, (_, score, g) in enumerate(self._buffer) if i != self.window_width) / (2.0 * self.window_width)
        if abs(average) >= 0.00001:
            ratio = min(target_score / average, 255.0)
        else:
            ratio = 255.0 if target_score >= self.min_content_val else 0.0
        if (ratio >= self.adaptive_threshold and target_score >= self.min_content_val
                and target_timecode - self._last_cut >= self.min_scene_len):
            self._last_cut = target_timecode
            return [target_timecode]
        if (self.weak_threshold is not None and self.weak_threshold <= ratio < self.adaptive_threshold
                and target_score >= self.min_content_val and target_timecode - self._last_cut >= self.min_scene_len):
            self.weak.append(target_timecode)
        return []


class RgbContentDetector(_RgbScore, ContentDetector):
    """ContentDetector fed RGB frames (see ``_RgbScore``)."""

    def process_frame(self, timecode: FrameTimecode, frame_img: np.ndarray, gap: int = 1,
                      hsv: np.ndarray | None = None) -> list[FrameTimecode]:
        """``gap`` and ``hsv`` are taken as RgbAdaptiveDetector takes them; ``gap`` is unused:
        this threshold is absolute."""
        self._hsv = hsv
        return super().process_frame(timecode, frame_img)
