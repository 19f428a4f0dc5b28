"""Overlay-text filter on synthetic footage: a textured plane panned under the camera, with
burned-in subtitles, a corner logo or a running clock drawn on top (the way broadcast and
camera overlays are: light glyphs with a dark outline or backing box)."""

from __future__ import annotations

import cv2
import numpy as np

from tasks.curate import overlay_text
from tasks.curate.overlay_text import OverlayTextConfig, judge, window_mask

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
