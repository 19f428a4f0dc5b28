"""Overlay-text filter on synthetic footage: a textured plane panned under the camera, with
burned-in subtitles, a corner logo or a running clock drawn on top (the way broadcast and
camera overlays are: light glyphs with a dark outline or backing box)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tasks.curate import overlay_text
from tasks.curate.overlay_text import (
    OverlayTextConfig,
    _text_rows,
    _without_stacked,
    bands,
    camera_speed,
    chroma_frames,
    judge,
    window_mask,
)

H, W, FPS, T = 144, 256, 30.0, 90
TIMES = np.arange(T) / FPS
FONT = cv2.FONT_HERSHEY_SIMPLEX


def scene(speed: float = 1.5, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    big = cv2.resize(rng.random((24, 70, 3)).astype(np.float32), (W + 200, H), interpolation=cv2.INTER_CUBIC)
    big = np.clip(big * 170 + 40, 0, 255).astype(np.uint8)
    for _ in range(120):
        c = tuple(int(v) for v in rng.integers(20, 235, 3))
        cv2.circle(big, (int(rng.integers(W + 200)), int(rng.integers(H))), int(rng.integers(3, 12)), c, -1)
    return np.stack([big[:, int(i * speed):int(i * speed) + W] for i in range(T)])


def outlined(frame: np.ndarray, text: str, org: tuple[int, int], scale: float) -> None:
    cv2.putText(frame, text, org, FONT, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(frame, text, org, FONT, scale, (255, 255, 255), 1, cv2.LINE_AA)


def with_subtitles(frames: np.ndarray) -> np.ndarray:
    out = frames.copy()
    lines = ["we walked to the old harbour", "and the boats were already gone"]
    for t in range(T):
        outlined(out[t], lines[t // 45], (40, 132), 0.4)  # a new line after 1.5 s
    return out


def test_subtitles_are_rejected_or_tagged():
    frames = with_subtitles(scene())
    verdict = judge(frames, TIMES, OverlayTextConfig())
    assert verdict.reason == "overlay_text", verdict.scores
    assert verdict.scores["text_area"] > 0.005
    tagged = judge(frames, TIMES, OverlayTextConfig(action="tag"))
    assert tagged.keep and "overlay:text" in tagged.tags


def test_clean_moving_footage_is_kept():
    verdict = judge(scene(), TIMES, OverlayTextConfig())
    assert verdict.keep and verdict.scores["text_area"] == 0.0, verdict.scores


def test_running_clock_in_a_corner():
    frames = scene()
    for t in range(T):
        stamp = f"2024-05-01 12:00:{t // 30:02d}.{t % 30:02d}"
        cv2.rectangle(frames[t], (126, 4), (252, 18), (0, 0, 0), -1)
        cv2.putText(frames[t], stamp, (130, 15), FONT, 0.32, (255, 255, 255), 1, cv2.LINE_AA)
    assert judge(frames, TIMES, OverlayTextConfig()).reason == "overlay_text"


def test_a_bright_bar_fixed_on_screen_is_not_text():
    # A fixed graphic without glyphs (a lit rail, a lower-third bar) has no upright strokes.
    frames = scene()
    frames[:, 120:124, 40:200] = 250
    assert judge(frames, TIMES, OverlayTextConfig()).keep


def test_a_frozen_shot_gives_no_verdict_from_averaging():
    # Nothing moves, so averaging cannot tell burned-in text from the picture.
    frames = with_subtitles(scene(speed=0.0))
    frames[:] = frames[0]
    assert judge(frames, TIMES, OverlayTextConfig()).keep


def test_text_on_drawn_pages_is_left_to_the_video_type_filter():
    frames = np.empty((T, H, W, 3), np.uint8)
    frames[:] = (245, 245, 240)
    for t in range(T):
        cv2.putText(frames[t], "Quarterly results", (15, 30), FONT, 0.6, (20, 20, 20), 2)
        cv2.putText(frames[t], f"- item {t // 30}", (25, 70), FONT, 0.45, (20, 20, 20), 1)
    verdict = judge(frames, TIMES, OverlayTextConfig())
    assert verdict.keep and "overlay:not_judged" in verdict.tags
    assert judge(frames, TIMES, OverlayTextConfig(enabled=False)).scores == {}



def floor_streaks(n: int = 6) -> np.ndarray:
    """n x 128 x 128 grey window of a fixed simulator floor: pairs of soft, overlapping bright
    streaks (as MuJoCo's speckled floor texture renders) with a disk moving across it."""
    big = np.full((512, 512), 94, np.uint8)
    for x, y in ((150, 112), (380, 360), (200, 470)):
        cv2.ellipse(big, (x, y), (20, 7), 0, 0, 360, 175, -1, cv2.LINE_AA)
        cv2.ellipse(big, (x + 24, y + 6), (20, 7), 0, 0, 360, 175, -1, cv2.LINE_AA)
    out = np.repeat(cv2.resize(big, (128, 128), interpolation=cv2.INTER_AREA)[None], n, axis=0)
    for t in range(n):
        cv2.circle(out[t], (40 + 6 * t, 80), 10, 200, -1)
    return out


def test_a_lone_streak_of_floor_texture_is_not_a_glyph_row():
    # Steady, bright and band-shaped, but each pixel row crosses one or two strokes, not several.
    window = floor_streaks()
    assert not window_mask(window, OverlayTextConfig()).any()
    assert window_mask(window, OverlayTextConfig(glyph_runs_min=0)).any()  # the rule is what rejects it


def test_a_yellow_clock_without_a_rim_on_a_bright_grey_ground():
    # Yellow glyphs have nearly the luma of a pale ground; their chroma still stands out.
    rng = np.random.default_rng(0)
    big = cv2.resize(rng.random((30, 90)).astype(np.float32), (W + 200, H), interpolation=cv2.INTER_CUBIC)
    big = np.repeat(np.clip(big * 60 + 180, 0, 255).astype(np.uint8)[..., None], 3, axis=2)
    frames = np.stack([big[:, int(i * 1.5):int(i * 1.5) + W] for i in range(T)])
    assert judge(frames, TIMES, OverlayTextConfig()).keep  # the pale ground alone has no text
    for t in range(T):
        cv2.putText(frames[t], f"2024-05-01 12:00:{t // 30:02d}", (150, 14), FONT, 0.3, (235, 235, 40), 1, cv2.LINE_AA)
    assert judge(frames, TIMES, OverlayTextConfig()).reason == "overlay_text"
    assert judge(frames, TIMES, OverlayTextConfig(chroma_text=False)).keep  # the chroma pass is what finds it


def test_the_second_line_of_a_two_line_subtitle_does_not_hide_the_first(monkeypatch):
    # Each line's steady neighbour is the other line; it must not count as steady scene around it.
    frames = scene(speed=0.5, seed=2)
    for f in frames:
        outlined(f, "we walked to the old harbour", (40, 118), 0.35)
        outlined(f, "and the boats were gone", (50, 132), 0.35)
    assert judge(frames, TIMES, OverlayTextConfig()).reason == "overlay_text"
    monkeypatch.setattr(overlay_text, "_without_stacked", lambda mask, box, rows: mask)
    assert judge(frames, TIMES, OverlayTextConfig()).keep  # the rule is what finds it


def test_chroma_frames_equal_the_numpy_reference(real_frames):
    for frames in [scene()[:6], *(f[:: max(1, len(f) // 6)][:6] for f in real_frames.values())]:
        assert np.array_equal(chroma_frames(frames), frames.max(axis=3) - frames.min(axis=3))
    assert np.array_equal(chroma_frames(scene()[:3, 10:100, 5:200]), scene()[:3, 10:100, 5:200].max(axis=3)
                          - scene()[:3, 10:100, 5:200].min(axis=3))


def locked_off(seed: int = 4) -> np.ndarray:
    """A locked-off camera: a fixed, softly shaded street with a walker crossing it. (Over busy
    crisp texture a still camera's overlays are not found at all: every stroke around them is
    steady, which ``ring_strokes_max`` reads as a still scene.)"""
    rng = np.random.default_rng(seed)
    street = cv2.resize(rng.random((9, 16, 3)).astype(np.float32), (W, H), interpolation=cv2.INTER_CUBIC)
    frames = np.repeat(np.clip(street * 120 + 60, 0, 255).astype(np.uint8)[None], T, axis=0)
    for t in range(T):
        cv2.rectangle(frames[t], (20 + 2 * t, 40), (34 + 2 * t, 100), (60, 50, 45), -1)
    return frames


def test_camera_speed_tells_a_pan_from_a_locked_off_shot():
    pan, still = scene(speed=1.5), locked_off()
    assert camera_speed(pan[0, ..., 1], pan[18, ..., 1], 0.6) > 0.1
    assert camera_speed(still[0, ..., 1], still[18, ..., 1], 0.6) < 0.01
    # A fixed caption in the bottom quarter does not pin a pan to zero.
    captioned = with_subtitles(pan)
    assert camera_speed(captioned[0, ..., 1], captioned[18, ..., 1], 0.6) > 0.1


def test_still_scene_detail_under_a_locked_off_camera_is_not_text():
    # Stability says nothing when the camera does not move: a lit kerb low in the picture (dim
    # strokes) and a sign mid-picture (crisp glyphs) are part of the scene.
    frames = locked_off()
    rng = np.random.default_rng(1)
    kerb = np.clip(170 + rng.normal(0, 25, (4, 60)), 0, 255).astype(np.uint8)[..., None]
    frames[:, 112:116, 150:210] = np.clip(frames[:, 112:116, 150:210] * 0.5 + kerb * 0.5, 0, 255).astype(np.uint8)
    for f in frames:
        outlined(f, "HARBOUR ST", (150, 70), 0.35)
    verdict = judge(frames, TIMES, OverlayTextConfig())
    assert verdict.keep, verdict.scores
    assert judge(frames, TIMES, OverlayTextConfig(locked_speed=0.0)).reason == "overlay_text"  # the rule is what keeps it


def test_overlays_on_a_locked_off_camera_are_still_found():
    subtitled = locked_off()
    for f in subtitled:
        outlined(f, "we walked to the old harbour", (40, 132), 0.4)
    assert judge(subtitled, TIMES, OverlayTextConfig()).reason == "overlay_text"
    clocked = locked_off()
    for t in range(T):
        cv2.rectangle(clocked[t], (126, 4), (252, 18), (0, 0, 0), -1)
        cv2.putText(clocked[t], f"2024-05-01 12:00:{t // 30:02d}.{t % 30:02d}", (130, 15), FONT, 0.32, (255, 255, 255), 1,
                    cv2.LINE_AA)
    assert judge(clocked, TIMES, OverlayTextConfig()).reason == "overlay_text"


def test_chaplin_street_scene_is_not_overlay_text(real_frames):
    frames = real_frames.get("chaplin.mp4")
    if frames is None:
        pytest.skip("chaplin.mp4 is not in ../shared/data/videos")
    times = np.arange(len(frames)) / 25.0
    assert judge(frames, times, OverlayTextConfig()).keep


# Per-row stroke fill of a real two-line subtitle blob (tuning seed 1, raw_0000, frame 133, at
# 256 px): the lines at rows 2-8 and 11-20 are joined by picture strokes between them.
JOINED_LINES = [0.08, 0.15, 0.30, 0.34, 0.89, 0.90, 0.89, 0.92, 0.96, 0.36, 0.35, 0.67, 0.76, 0.65, 0.49, 0.38,
                0.79, 0.79, 0.77, 0.78, 0.78, 0.49, 0.30, 0.01]


def test_two_subtitle_lines_joined_by_picture_strokes_are_cut_into_rows():
    fill = np.array(JOINED_LINES)
    assert _text_rows(fill, 14.4, 0.6) == [(2, 10), (11, 23)]  # each no taller than a text row
    assert _text_rows(fill, 14.4, 0.0) == [(2, 23)]  # without the cut: one run, too tall to be text
    strokes = np.zeros((144, 256), bool)
    for r, f in enumerate(fill):  # a blob with that profile, rows 115-138
        strokes[115 + r, 60: 60 + max(1, round(f * 140))] = True
    rows = bands(strokes, OverlayTextConfig())
    assert [(y, h) for _, y, _, h in rows] == [(117, 8), (126, 12)]
    assert bands(strokes, OverlayTextConfig(row_split=0.0)) == []


def test_the_other_pieces_of_a_text_line_are_not_scene_around_it():
    mask = np.ones((40, 120), bool)
    first, rest, far, below = (10, 10, 30, 6), (48, 11, 30, 6), (100, 30, 10, 6), (12, 18, 28, 6)
    cleared = _without_stacked(mask, first, [first, rest, far, below])
    assert not cleared[11:17, 48:78].any() and not cleared[18:24, 12:40].any()  # same line, line below
    assert cleared[30:36, 100:110].all() and cleared[10:16, 10:40].all()  # elsewhere, and the box itself
