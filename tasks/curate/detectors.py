"""PySceneDetect's hard-cut detectors, fed the splitter's RGB frames.

The stock detectors take BGR frames and measure frame differences on int32 numpy copies; the
classes here take RGB (the analysis frames' order, so no BGR copy is made) and difference
uint8 planes in OpenCV. Scores and cuts are bit for bit the stock ones: the sums are exact
integers either way, and test_scenes checks every frame score against the stock detector
on real footage.
"""

from __future__ import annotations

import cv2
import numpy as np
from scenedetect.common import FrameTimecode
from scenedetect.detectors import AdaptiveDetector, ContentDetector


class _RgbScore:
    """ContentDetector's frame score on RGB frames (PySceneDetect 0.7 with its default weights:
    hue, saturation and value; no edges and no stats manager, which the splitter never sets)."""

    def _calculate_frame_score(self, timecode: FrameTimecode, frame_img: np.ndarray) -> float:
        hue, sat, lum = cv2.split(cv2.cvtColor(frame_img, cv2.COLOR_RGB2HSV))
        last, self._last_frame = self._last_frame, ContentDetector._FrameData(hue, sat, lum, None)
        if last is None:
            return 0.0
        pixels = float(hue.shape[0] * hue.shape[1])
        planes = ((hue, last.hue), (sat, last.sat), (lum, last.lum))
        components = ContentDetector.Components(
            *(cv2.sumElems(cv2.absdiff(a, b))[0] / pixels for a, b in planes), delta_edges=0.0)
        return sum(c * w for c, w in zip(components, self._weights, strict=True)) / sum(abs(w) for w in self._weights)


class RgbAdaptiveDetector(_RgbScore, AdaptiveDetector):
    """AdaptiveDetector fed RGB frames (see ``_RgbScore``)."""


class RgbContentDetector(_RgbScore, ContentDetector):
    """ContentDetector fed RGB frames (see ``_RgbScore``)."""
