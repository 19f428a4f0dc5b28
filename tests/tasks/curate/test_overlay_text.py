"""Overlay-text filter on synthetic footage (a textured plane panned under the camera, with
burned-in subtitles, a corner logo or a running clock drawn on top, the way broadcast and
camera overlays are) and on real footage from ../shared/data when it is there."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tasks.curate.overlay_text import OverlayTextConfig, judge, persistent, same_place

H, W, FPS, T = 144, 256, 30.0, 90
TIMES = np.arange(T) / FPS
FONT = cv2.FONT_HERSHEY_SIMPLEX


def panorama(seed: int = 0, width: int = W + 200) -> np.ndarray:
    rng = np.random.default_rng(seed)
    big = cv2.resize(rng.random((24, 70, 3)).astype(np.float32), (width, H), interpolation=cv2.INTER_CUBIC)
    big = np.clip(big * 170 + 40, 0, 255).astype(np.uint8)
    for _ in range(120):
        c = tuple(int(v) for v in rng.integers(20, 235, 3))
        cv2.circle(big, (int(rng.integers(width)), int(rng.integers(H))), int(rng.integers(3, 12)), c, -1)
    return big


def pan(big: np.ndarray, speed: float = 1.5) -> np.ndarray:
    return np.stack([big[:, int(i * speed):int(i * speed) + W] for i in range(T)])


def scene(speed: float = 1.5, seed: int = 0) -> np.ndarray:
    return pan(panorama(seed), speed)


def outlined(frame: np.ndarray, text: str, org: tuple[int, int], scale: float) -> None:
    cv2.putText(frame, text, org, FONT, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(frame, text, org, FONT, scale, (255, 255, 255), 1, cv2.LINE_AA)


def with_subtitles(frames: np.ndarray) -> np.ndarray:
    out = frames.copy()
    lines = ["we walked to the old harbour", "and the boats were already gone"]
    for t in range(T):
        outlined(out[t], lines[t // 45], (40, 132), 0.4)  # a new line after 1.5 s
    return out


def clocked(frames: np.ndarray) -> np.ndarray:
    out = frames.copy()
    for t in range(T):
        cv2.rectangle(out[t], (126, 4), (252, 18), (0, 0, 0), -1)
        cv2.putText(out[t], f"2024-05-01 12:00:{t // 30:02d}.{t % 30:02d}", (130, 15), FONT, 0.32, (255, 255, 255), 1,
                    cv2.LINE_AA)
    return out


def locked_off(seed: int = 4) -> np.ndarray:
    """A locked-off camera: a fixed, softly shaded street with a walker crossing it."""
    rng = np.random.default_rng(seed)
    street = cv2.resize(rng.random((9, 16, 3)).astype(np.float32), (W, H), interpolation=cv2.INTER_CUBIC)
    frames = np.repeat(np.clip(street * 120 + 60, 0, 255).astype(np.uint8)[None], T, axis=0)
    for t in range(T):
        cv2.rectangle(frames[t], (20 + 2 * t, 40), (34 + 2 * t, 100), (60, 50, 45), -1)
    return frames


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
    assert judge(clocked(scene()), TIMES, OverlayTextConfig()).reason == "overlay_text"


def test_scene_text_moving_with_the_camera_is_not_overlay():
    # A shop sign and a poster are painted on the panorama: the detector sees text on every
    # frame, but it slides across the screen with the pan, so it is not burned in.
    big = panorama(seed=3, width=W + 300)
    for x in (20, 190, 330):
        cv2.rectangle(big, (x - 4, 20), (x + 120, 42), (240, 240, 225), -1)
        cv2.putText(big, "HARBOUR ST", (x, 37), FONT, 0.5, (20, 20, 30), 1, cv2.LINE_AA)
    cv2.rectangle(big, (100, 100), (260, 125), (30, 30, 90), -1)
    cv2.putText(big, "FRESH FISH DAILY", (104, 118), FONT, 0.45, (250, 250, 250), 1, cv2.LINE_AA)
    frames = pan(big, speed=2.5)
    verdict = judge(frames, TIMES, OverlayTextConfig())
    assert verdict.keep and verdict.scores["text_area"] == 0.0, verdict.scores
    # The same signs, also captioned: the caption is still found.
    assert judge(with_subtitles(frames), TIMES, OverlayTextConfig()).reason == "overlay_text"


def test_a_bright_bar_fixed_on_screen_is_not_text():
    # A fixed graphic without glyphs (a lit rail, a lower-third bar) is not text.
    frames = scene()
    frames[:, 120:124, 40:200] = 250
    assert judge(frames, TIMES, OverlayTextConfig()).keep


def test_text_on_drawn_pages_is_left_to_the_video_type_filter():
    frames = np.empty((T, H, W, 3), np.uint8)
    frames[:] = (245, 245, 240)
    for t in range(T):
        cv2.putText(frames[t], "Quarterly results", (15, 30), FONT, 0.6, (20, 20, 20), 2)
        cv2.putText(frames[t], f"- item {t // 30}", (25, 70), FONT, 0.45, (20, 20, 20), 1)
        cv2.putText(frames[t], "page 3 of 12", (150, 130), FONT, 0.4, (20, 20, 20), 1)
    verdict = judge(frames, TIMES, OverlayTextConfig())
    assert verdict.keep and "overlay:not_judged" in verdict.tags
    assert judge(frames, TIMES, OverlayTextConfig(skip_drawn=False)).reason == "overlay_text"
    assert judge(frames, TIMES, OverlayTextConfig(enabled=False)).scores == {}


def test_a_yellow_clock_without_a_rim_on_a_bright_grey_ground():
    rng = np.random.default_rng(0)
    big = cv2.resize(rng.random((30, 90)).astype(np.float32), (W + 200, H), interpolation=cv2.INTER_CUBIC)
    big = np.repeat(np.clip(big * 60 + 120, 0, 255).astype(np.uint8)[..., None], 3, axis=2)
    frames = np.stack([big[:, int(i * 1.5):int(i * 1.5) + W] for i in range(T)])
    assert judge(frames, TIMES, OverlayTextConfig()).keep  # the ground alone has no text
    for t in range(T):
        cv2.putText(frames[t], f"2024-05-01 12:00:{t // 30:02d}", (140, 14), FONT, 0.32, (235, 235, 40), 1,
                    cv2.LINE_AA)
    assert judge(frames, TIMES, OverlayTextConfig()).reason == "overlay_text"


def test_scene_text_mid_picture_under_a_locked_off_camera_is_not_overlay():
    # Under a still camera a sign persists on screen like an overlay; only where it sits tells.
    frames = locked_off()
    for f in frames:
        outlined(f, "HARBOUR ST", (140, 70), 0.45)
    verdict = judge(frames, TIMES, OverlayTextConfig())
    assert verdict.keep, verdict.scores
    assert judge(frames, TIMES, OverlayTextConfig(zone_top=0.6, zone_bottom=0.4)).reason == "overlay_text"  # the zone is what keeps it


def test_overlays_on_a_locked_off_camera_are_still_found():
    subtitled = locked_off()
    for f in subtitled:
        outlined(f, "we walked to the old harbour", (40, 132), 0.4)
    assert judge(subtitled, TIMES, OverlayTextConfig()).reason == "overlay_text"
    assert judge(clocked(locked_off()), TIMES, OverlayTextConfig()).reason == "overlay_text"


def test_text_seen_on_one_sample_only_does_not_persist():
    a, b, c = (10, 120, 100, 10), (11, 121, 120, 9), (150, 10, 60, 8)
    assert same_place(a, b, 0.6) and not same_place(a, c, 0.6)
    assert same_place(a, (4, 120, 112, 10), 0.6)  # a centred line whose words changed
    assert not same_place(a, (40, 120, 100, 10), 0.6)  # the same line carried 30 px by a pan
    # Two signs cut off by the picture's right border share that border, not an end.
    assert same_place((219, 24, 37, 16), (190, 25, 66, 15), 0.6)
    assert not same_place((219, 24, 37, 16), (190, 25, 66, 15), 0.6, width=256)
    config = OverlayTextConfig()
    assert persistent([[a], [b], []], config) == [a, b]  # two of three samples
    assert persistent([[a], [c], []], config) == []  # each once


# Real footage (../shared/data): the burned-in CCTV clock and camera label are found; people,
# hikers and a film's live-action shots are not overlay text.

def _real(folder: str, name: str):
    from tasks.curate.decode import analysis_frames
    from tests.support import SHARED_DATA

    path = SHARED_DATA / folder / name
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    frames, times = [], []
    for f in analysis_frames(path):
        frames.append(f.image)
        times.append(f.time)
    return np.stack(frames), np.asarray(times)


def test_real_cctv_timestamp_is_overlay_text():
    frames, times = _real("videos-dev", "cctv_timestamp.avi")
    verdict = judge(frames, times, OverlayTextConfig())
    assert verdict.reason == "overlay_text", verdict.scores


@pytest.mark.parametrize("name", ["tos.mp4", "hikers.mp4", "group.mp4"])
def test_real_footage_without_overlays_is_kept(name):
    frames, times = _real("videos-dev", name)
    verdict = judge(frames, times, OverlayTextConfig())
    assert verdict.keep and verdict.scores["text_area"] == 0.0, verdict.scores


def test_chaplin_street_scene_is_not_overlay_text(real_frames):
    frames = real_frames.get("chaplin.mp4")
    if frames is None:
        pytest.skip("chaplin.mp4 is not in ../shared/data/videos")
    assert judge(frames, np.arange(len(frames)) / 25.0, OverlayTextConfig()).keep
