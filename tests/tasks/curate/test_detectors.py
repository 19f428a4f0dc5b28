"""The RGB-fed cut detectors against PySceneDetect's own, frame score by frame score."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scenedetect.common import FrameTimecode
from scenedetect.detectors import AdaptiveDetector, ContentDetector

from tasks.curate.decode import analysis_frames
from tasks.curate.detectors import RgbAdaptiveDetector, RgbContentDetector
from tests.support import SHARED_DATA
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


def test_adaptive_ratio_accounts_for_frames_left_undecoded():
    # bikes.mp4 as the analysis pass decodes it (reference frames only): the cut at frame 76
    # comes right after a decoded frame (gap 1) while its neighbours span two frames of a
    # pan. Read as consecutive frames its ratio falls under the threshold; scaled to its gap
    # it is found, with the other four.
    path = SHARED_DATA / "videos" / "bikes.mp4"
    if not path.exists():
        pytest.skip("../shared/data is absent")
    frames = list(analysis_frames(path))
    assert len(frames) < 250

    def cuts(use_gaps: bool) -> list[int]:
        detector, found, previous = RgbAdaptiveDetector(min_scene_len=3), [], None
        for f in frames:
            small = cv2.resize(f.image, (f.image.shape[1] // 2, f.image.shape[0] // 2), interpolation=cv2.INTER_AREA)
            gap = f.index - previous if previous is not None and use_gaps else 1
            found += [round(c.seconds * 25) for c in detector.process_frame(FrameTimecode(f.index, fps=25.0), small, gap)]
            previous = f.index
        return found

    assert cuts(use_gaps=True) == [30, 76, 137, 187, 242]
    assert 76 not in cuts(use_gaps=False)
