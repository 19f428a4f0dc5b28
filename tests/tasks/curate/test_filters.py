"""run_filters (all filters, merged scores, first rejecting stage), the default configs, and
precision_recall for the bench."""

from __future__ import annotations

import math
import time
from typing import ClassVar

import pytest

from tasks.curate.filter_base import FilterConfig, Verdict
from tasks.curate.filters import confusion, default_configs, precision_recall, run_filters
from tasks.curate.motion import MotionConfig
from tasks.curate.quality import QualityConfig
from tests.tasks.curate.test_filter_base import scene


def test_run_filters_runs_every_filter_and_reports_the_first_rejection():
    frames, times = scene(60, speed=0.0)  # a locked-off still shot
    merged, per_filter = run_filters(frames, times)
    assert [v.stage for v in per_filter] == ["motion", "quality", "overlay_text", "video_type"]
    assert not merged.keep and merged.stage == "motion" and merged.reason == "static"
    # Filters after the rejecting one still ran: their scores are in the merged verdict.
    for name in ("moving_fraction", "sharpness", "text_area", "type_colours"):
        assert name in merged.scores
    assert "type:physical" in merged.tags and "camera:still" in merged.tags
    moving, _ = run_filters(*scene(60))
    assert moving.keep and moving.reason is None and moving.stage is None


def test_disabled_filters_are_skipped():
    frames, times = scene(60, speed=0.0)
    merged, per_filter = run_filters(frames, times, [MotionConfig(enabled=False), QualityConfig()])
    assert [v.stage for v in per_filter] == ["quality"]
    assert merged.keep and "moving_fraction" not in merged.scores


class ClashConfig(FilterConfig):
    stage: ClassVar[str] = "clash"

    def judge(self, frames, times):
        return Verdict(keep=True, scores={"motion_mean": 0.0})


def test_a_score_name_used_twice_is_an_error():
    frames, times = scene(30)
    with pytest.raises(ValueError, match="motion_mean"):
        run_filters(frames, times, [MotionConfig(), ClashConfig()])


def test_default_configs_are_the_four_stages_in_order():
    assert [c.stage for c in default_configs()] == ["motion", "quality", "overlay_text", "video_type"]


def test_precision_recall_counts():
    predicted = ["static", None, "shake", "static", None, None]
    labels = ["static", "static", "blur", "shake", None, "shake"]
    pr = precision_recall(predicted, labels, {"static", "shake"})
    assert (pr.tp, pr.fp, pr.fn, pr.tn) == (2, 1, 2, 1)
    assert pr.precision == pytest.approx(2 / 3) and pr.recall == pytest.approx(0.5)
    none = precision_recall([None, None], [None, "blur"], {"static"})
    assert math.isnan(none.precision) and math.isnan(none.recall)
    with pytest.raises(ValueError, match="2 predictions for 3 labels"):
        precision_recall([None, None], [None, None, None], {"static"})


def test_confusion_table():
    table = confusion(["static", None, None], ["static", None, "blur"])
    assert table == {("static", "static"): 1, ("clean", "keep"): 1, ("blur", "keep"): 1}


def test_all_filters_are_faster_than_decode():
    # Decode of 256-px analysis frames runs at several hundred frames per second; the four
    # filters together must cost well under that (measured: over 1000 frames/s on one core).
    frames, times = scene(300)
    run_filters(frames[:60], times[:60])  # warm up OpenCV
    start = time.perf_counter()
    run_filters(frames, times)
    fps = len(frames) / (time.perf_counter() - start)
    assert fps > 400, f"{fps:.0f} analysis frames per second"
