"""The RGB-fed cut detectors against PySceneDetect's own, frame score by frame score."""

from __future__ import annotations

import tomllib

import cv2
import numpy as np
import pytest
import scenedetect
from packaging.requirements import Requirement
from scenedetect.common import FrameTimecode
from scenedetect.detectors import AdaptiveDetector, ContentDetector

from tasks.curate.decode import AnalysisConfig, analysis_frames
from tasks.curate.detectors import GAP_POWER, RgbAdaptiveDetector, RgbContentDetector
from tests.support import REPO, SHARED_DATA
from tests.tasks.curate.test_scenes import FPS, PLAN, edit


def same_as_stock(clips) -> None:
    # The stock PySceneDetect detectors take BGR; ours take the RGB frames directly and sum
    # differences in OpenCV. Every frame score and every cut must be the same.
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


def test_rgb_detectors_score_and_cut_exactly_as_the_stock_ones_on_generated_video(make_video):
    # Edited shots (cuts, a fade, dissolves) as made, and as the analysis pass decodes them
    # from H.264: no ../shared/data needed.
    frames = edit(PLAN)[0]
    decoded = [f.image for f in analysis_frames(make_video(frames, fps=FPS), AnalysisConfig(skip_unreferenced=False))]
    same_as_stock([np.stack(frames), np.stack(decoded)])


def test_rgb_detectors_score_and_cut_exactly_as_the_stock_ones_on_real_footage(real_frames):
    same_as_stock(list(real_frames.values()))


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


def test_adaptive_ratio_scales_the_neighbours_to_the_frames_gap():
    # Grey frames numbered as a decode that leaves out unreferenced frames numbers them: the
    # change into frame 7 spans one frame, its neighbours' two. Frame scores (|change of
    # value| / 3 on grey): 10, 10, 10, 25, 10, 10. The stock ratio 25 / 10 = 2.5 stays under the
    # threshold 3; scaled to the gap, 25 / (10 / 2 ** GAP_POWER) = 3.5 is a cut.
    index = [0, 2, 4, 6, 7, 9, 11]
    frames = [np.full((36, 64, 3), v, np.uint8) for v in (100, 130, 100, 130, 205, 175, 205)]
    assert 25 / (10 / 2 ** GAP_POWER) >= 3 > 25 / 10

    def cuts(detector, gaps: list[int] | None) -> list[int]:
        found = []
        for k, (i, frame) in enumerate(zip(index, frames, strict=True)):
            code = FrameTimecode(i, fps=25.0)
            if gaps is None:  # the stock detector, on BGR
                found += detector.process_frame(code, cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
            else:
                found += detector.process_frame(code, frame, gaps[k])
        return [round(c.seconds * 25) for c in found]

    gaps = [1] + list(np.diff(index))
    assert cuts(RgbAdaptiveDetector(min_scene_len=3), gaps) == [7]
    assert cuts(RgbAdaptiveDetector(min_scene_len=3), [1] * len(index)) == []
    assert cuts(AdaptiveDetector(min_scene_len=3), None) == []


def test_pyscenedetect_is_pinned_to_the_minor_version_the_override_is_written_against():
    # detectors.py overrides ContentDetector._calculate_frame_score and reads private state
    # (_last_frame, _FrameData, Components, _weights, _buffer, _last_cut) as 0.7 has them.
    dependencies = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["dependencies"]
    pin = next(Requirement(d) for d in dependencies if Requirement(d).name == "scenedetect-headless")
    assert pin.specifier.contains(scenedetect.__version__) and scenedetect.__version__.startswith("0.7.")
    assert not pin.specifier.contains("0.8.0") and not pin.specifier.contains("0.6.6")
    assert hasattr(ContentDetector, "_calculate_frame_score") and hasattr(ContentDetector, "_FrameData")
    assert ContentDetector.Components._fields == ("delta_hue", "delta_sat", "delta_lum", "delta_edges")
