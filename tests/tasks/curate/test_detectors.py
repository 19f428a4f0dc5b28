"""The RGB-fed cut detectors against PySceneDetect's own, frame score by frame score."""

from __future__ import annotations

import cv2
import numpy as np
from scenedetect.common import FrameTimecode
from scenedetect.detectors import AdaptiveDetector, ContentDetector

from tasks.curate.detectors import RgbAdaptiveDetector, RgbContentDetector
from tests.tasks.curate.test_scenes import PLAN, edit


def test_rgb_detectors_score_and_cut_exactly_as_the_stock_ones_on_bgr(real_frames):
    # The stock PySceneDetect detectors take BGR; ours take the RGB frames directly and sum
    # differences in OpenCV. Every frame score and every cut must be the same.
    clips = [np.stack(edit(PLAN)[0])] + list(real_frames.values())
    for frames in clips:
        halves = [cv2.resize(f, (f.shape[1] // 2, f.shape[0] // 2), interpolation=cv2.INTER_AREA) for f in frames]
        pairs = ((AdaptiveDetector(min_scene_len=3), RgbAdaptiveDetector(min_scene_len=3)),
                 (ContentDetector(min_scene_len=3), RgbContentDetector(min_scene_len=3)))
        for stock, ours in pairs:
            for i, small in enumerate(halves):
                code = FrameTimecode(i, fps=25.0)
                expected = stock.process_frame(code, cv2.cvtColor(small, cv2.COLOR_RGB2BGR))
                assert ours.process_frame(code, small) == expected
                assert ours._frame_score == stock._frame_score
