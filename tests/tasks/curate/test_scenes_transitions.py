"""Transition checks on generated frames: what a dissolve or fade is, and what only looks like one."""

from __future__ import annotations

import cv2
import pytest
import numpy as np

from tasks.curate.decode import AnalysisFrame
from tasks.curate.scenes import split_scenes

from .test_scenes import FPS, H, W, plane, shot


def spans_of(frames):
    return [(s.start_frame, s.end_frame, s.detail or s.cause)
            for s in split_scenes((AnalysisFrame(i, i / FPS, f) for i, f in enumerate(frames)), FPS, keep_frames=False)
            if s.kind == "transition" or s.cause == "cut"]


def zoom(seed: int, scales, gains):
    big = plane(seed, W + 400, H + 100)
    centre = (big.shape[1] / 2, big.shape[0] / 2)
    out = []
    for scale, gain in zip(scales, gains, strict=True):
        m = cv2.getRotationMatrix2D(centre, 0, scale)
        m[:, 2] += [W / 2 - centre[0], H / 2 - centre[1]]
        frame = gain * cv2.warpAffine(big, m, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        out.append(np.clip(frame, 0, 255).astype(np.uint8))
    return out


def test_a_zoom_with_an_exposure_change_is_not_a_dissolve():
    # Blurred thumbnails of a quick zoom while auto-exposure darkens the frame change
    # smoothly and almost linearly, as a blend would: the middle frame is a shifted, darker
    # copy of an end, which local motion with a gain explains better than a blend does.
    n = 12
    scales = [1.0] * 60 + list(np.linspace(1, 1.3, n)) + [1.3] * 60
    gains = [1.0] * 60 + list(np.linspace(1, 0.6, n)) + [0.6] * 60
    assert spans_of(zoom(5, scales, gains)) == []


def test_a_dissolve_between_views_of_one_place_is_still_a_dissolve():
    # Two views of the same texture, far enough apart that no local shift maps one on the other.
    a, b = zoom(5, [1.0] * 70, [1.0] * 70), zoom(5, [2.2] * 70, [1.0] * 70)
    mix = [np.clip((1 - w) * a[0].astype(np.float32) + w * b[0], 0, 255).astype(np.uint8)
           for w in np.linspace(0, 1, 14)[1:-1]]
    found = spans_of(a + mix + b)
    # (Still shots either side read as blends with weight 0 or 1, so the span may reach into them.)
    assert len(found) == 1 and found[0][2] == "dissolve" and found[0][0] <= 70 and found[0][1] >= 82


def black_join(hold: int, ramp: int, cut_first: bool):
    """70 frames of one shot, then either a hard cut to ``hold`` black frames and a fade in
    over ``ramp`` frames (``cut_first``), or a fade out over ``ramp`` frames, ``hold`` black
    frames and a hard cut; then 70 frames of another shot."""
    a, b = shot(1, 0.9), shot(2, 1.2)
    black = np.zeros((H, W, 3), np.float32)
    frames = [next(a) for _ in range(70)]
    if cut_first:
        frames += [black] * hold + [next(b) * ((j + 1) / (ramp + 1)) for j in range(ramp)]
    else:
        frames += [next(a) * (1 - (j + 1) / (ramp + 1)) for j in range(ramp)] + [black] * hold
    frames += [next(b) for _ in range(70)]
    return [np.clip(f, 0, 255).astype(np.uint8) for f in frames]


@pytest.mark.parametrize("hold", [1, 4])
def test_a_hard_cut_to_black_then_a_fade_in_is_a_cut_and_a_fade(hold):
    # The black frames after the cut are a too-short span; the fade is the ramp up only.
    assert spans_of(black_join(hold, 8, cut_first=True)) == [(70, 70 + hold, "cut"), (70 + hold, 78 + hold, "fade")]


@pytest.mark.parametrize("hold", [1, 4])
def test_a_fade_out_then_a_hard_cut_out_of_black_is_a_fade_and_a_cut(hold):
    spans = spans_of(black_join(hold, 8, cut_first=False))
    assert spans == [(70, 78, "fade"), (78 + hold, 148 + hold, "cut")]


def test_something_passing_right_in_front_of_the_lens_is_not_a_cut():
    # Three frames of an unrelated, closer object covering the whole picture, then the same
    # pan again: the view left and came back, so the shot goes on.
    frames = [f for f, _ in zip(shot(1, 0.9), range(120))]
    cover = plane(7)[:H, :W]
    for k in range(60, 63):
        frames[k] = cover
    frames = [np.clip(f, 0, 255).astype(np.uint8) for f in frames]
    assert spans_of(frames) == []
    # A new shot instead of the old view after the same three frames is a cut.
    other = [f for f, _ in zip(shot(2, 1.2), range(57))]
    changed = frames[:63] + [np.clip(f, 0, 255).astype(np.uint8) for f in other]
    assert [s[0] for s in spans_of(changed)] == [60]


def whip(jump: float):
    """A slow pan over ``plane(3)`` that jumps ``jump`` px sideways between frames 59 and 60."""
    big = plane(3, W + 400, H + 60)
    out = []
    for t in range(120):
        x = 40 + 0.5 * t + (jump if t >= 60 else 0)
        m = np.float32([[1, 0, -x], [0, 1, -30]])
        out.append(np.clip(cv2.warpAffine(big, m, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT),
                           0, 255).astype(np.uint8))
    return out


def test_a_whip_pan_is_not_a_cut():
    # The frames either side of the jump are one view moved a tenth of the picture: the
    # detector's peak is camera motion (armwrestle.mp4 206).
    assert spans_of(whip(14)) == []
    # A new shot at the same moment is still a cut.
    other = [np.clip(f, 0, 255).astype(np.uint8) for f, _ in zip(shot(8, 0.5), range(60))]
    assert [s[0] for s in spans_of(whip(14)[:60] + other)] == [60]


def test_a_source_shorter_than_the_detector_window_is_judged_on_its_pictures():
    # Three slides, one frame each (slides.avi): the detector's window never fills.
    slides = []
    for k, lines in enumerate((["TITLE"], ["lorem ipsum dolor", "sit amet, consec", "tetur adipiscing"],
                               ["All human beings", "are born free and", "equal in dignity", "and rights."])):
        page = np.full((H, W, 3), 250, np.uint8)
        for j, line in enumerate(lines):
            cv2.putText(page, line, (8 + 30 * (k == 0) + 40 * (k == 2), 20 + 18 * j + 20 * (k == 0) + 9 * (k == 2)), cv2.FONT_HERSHEY_SIMPLEX,
                        0.9 if k == 0 else 0.45, (20, 20, 20), 1 + (k == 0), cv2.LINE_AA)
        slides.append(page)
    assert [s[0] for s in spans_of(slides)] == [1, 2]
    # The same picture three times is one shot.
    assert spans_of([slides[0]] * 3) == []


def letterboxed(frames, bar: int = 12):
    """uint8 frames with black bars ``bar`` px high at the top and the bottom."""
    out = []
    for frame in frames:
        frame = np.clip(frame, 0, 255).astype(np.uint8)
        frame[:bar] = frame[-bar:] = 0
        out.append(frame)
    return out


def test_a_weak_peak_between_unrelated_pictures_is_a_cut():
    # A fast pan cut to another fast pan inside letterbox bars: the cut's HSV score is only
    # 2.6 times its neighbours' (threshold 3), as on sintel.mp4 76 and 118. Without the bars
    # the two pictures are unrelated (best-shift correlation < 0.35): a cut.
    a = letterboxed(f for f, _ in zip(shot(1, 6), range(60)))
    b = letterboxed(f for f, _ in zip(shot(7, 6), range(60)))
    assert [s[0] for s in spans_of(a + b)] == [60]
    # A weak peak of the same view (an exposure pop, ratio 2.35) is no cut.
    pop = letterboxed(f * (1.0 if i < 60 else 1.5) for i, (f, _) in enumerate(zip(shot(1, 2), range(120))))
    assert spans_of(pop) == []


def test_the_picture_coming_back_after_a_concealment_smear_is_not_a_cut():
    # A pan; at 60 the decoder conceals a lost slice (rows stretched down into streaks) and
    # holds that broken picture until 90, when the next intra frame brings the pan back
    # (armwrestle.mp4 229-268). The stream recovered: no cut, at 60 or at 90.
    frames = [np.clip(f, 0, 255).astype(np.uint8) for f, _ in zip(shot(1, 0.9), range(150))]
    smear = frames[59].copy()
    detail = np.random.default_rng(0).normal(0, 12, (W, 1))  # the stretched row's fine detail
    smear[H // 3:] = np.clip(smear[H // 3 - 1] + detail, 0, 255).astype(np.uint8)
    broken = frames[:60] + [smear] * 30 + frames[90:]
    assert [s for s in spans_of(broken) if s[2] == "cut"] == []
    # The same held picture without the smear (a frozen shot, then another shot) is a cut.
    other = [np.clip(f, 0, 255).astype(np.uint8) for f, _ in zip(shot(5, 1.2), range(60))]
    frozen = frames[:60] + [frames[59]] * 30 + other
    assert [s[0] for s in spans_of(frozen)] == [90]
