"""Cuts on real footage from the development set (skipped when ../shared/data is absent)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tasks.curate.decode import AnalysisConfig
from tasks.curate.scenes import boundaries, cut_f1, detect_scenes

DEV = Path(__file__).resolve().parents[3] / "../shared/data/videos-dev"
pytestmark = pytest.mark.skipif(not (DEV / "labels.json").is_file(), reason="no ../shared/data/videos-dev")


def _labels() -> dict:
    return json.loads((DEV / "labels.json").read_text())


def _cuts(name: str, analysis: AnalysisConfig = AnalysisConfig()) -> list[int]:
    spans = detect_scenes(DEV / name, analysis=analysis, include_rejected=True)
    return [b for b in boundaries(spans) if isinstance(b, int)]


def test_live_action_cuts_are_found_exactly():
    truth = _labels()["tos.mp4"]
    spans = detect_scenes(DEV / "tos.mp4", include_rejected=True)
    f = cut_f1(boundaries(spans), truth["hard_cuts"], truth["transitions"])
    assert f["f1"] == 1.0, f


def test_fast_decode_loses_no_cut_of_a_fast_cut_cgi_clip():
    # Sintel cuts every 18 to 36 frames; the reference-frames-only decode used to lose the
    # cuts at 58, 176 and 209 that a full decode finds.
    truth = _labels()["sintel.mp4"]["hard_cuts"]
    fast = _cuts("sintel.mp4")
    full = _cuts("sintel.mp4", AnalysisConfig(skip_unreferenced=False))
    assert set(full) <= set(fast)
    assert {58, 176, 209} <= set(fast)
    assert all(any(abs(c - t) <= 2 for t in truth) for c in fast)  # no false cut


@pytest.mark.parametrize("name", ["basketball.mp4", "makeup_webcam.avi"])
def test_handheld_and_webcam_motion_is_no_dissolve(name):
    # Shake, head turns and exposure drift fit a blend on blurred thumbnails; both files are
    # one shot, and local motion of one end explains their middle frames as well as a blend.
    spans = detect_scenes(DEV / name, include_rejected=True)
    assert [s for s in spans if s.kind == "transition"] == []


def test_weak_peaks_between_unrelated_pictures_are_cuts():
    # sintel.mp4 76 and 118 peak below the detector's threshold (motion-blurred fight on either
    # side); inside the letterbox bars the pictures either side are unrelated. Caminandes' cars
    # crossing the lens (correlation 0.46 and up) stay one shot.
    truth = _labels()["sintel.mp4"]["hard_cuts"]
    fast = _cuts("sintel.mp4")
    assert {58, 76, 118, 140, 176, 209} <= set(fast)
    assert all(any(abs(c - t) <= 2 for t in truth) for c in fast)
    assert _cuts("caminandes.mp4") == []


def test_a_weak_peak_between_alike_layouts_is_a_cut_by_its_edges():
    # sintel.mp4 96: one snowy fight cut to another, dark figures on a white ground either
    # side (picture correlation 0.68 inside the bars) but no edge in common (0.42).
    assert 96 in _cuts("sintel.mp4")


def test_the_stream_recovering_after_a_concealment_is_not_a_cut():
    # armwrestle.mp4: concealment smear at 229, held to 267, the picture back at 268.
    assert _cuts("armwrestle.mp4") == []
