"""Overlay-text filter on synthetic footage (a textured plane panned under the camera, with
burned-in subtitles, a corner logo or a running clock drawn on top, the way broadcast and
camera overlays are) and on real footage from ../shared/data when it is there."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tasks.curate.overlay_text import OverlayTextConfig, judge, overlay_candidates, persistent, same_place, text_lines

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


def test_many_scattered_short_words_are_a_text_filled_scene():
    # A caption the detector split into words is one line; five short words at scattered
    # places in the bands (spine titles, shop signs) are a text-filled scene, where only a
    # caption-long line stays a candidate.
    words = [(40, 120, 30, 8), (74, 120, 20, 8), (98, 121, 40, 8)]
    assert text_lines(words, 1.5) == 1
    spines = [(10, 5, 14, 7), (80, 8, 12, 6), (200, 4, 10, 6), (30, 118, 12, 6), (150, 125, 14, 7)]
    assert text_lines(spines, 1.5) == 5
    config = OverlayTextConfig()
    assert overlay_candidates(spines, H, config) == []
    caption = (50, 130, 150, 10)
    assert overlay_candidates([*spines, caption], H, config) == [caption]
    assert overlay_candidates(spines[:3], H, config) == spines[:3]  # a few words: may be labels


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


# The two failures a user reported with the old stroke-morphology filter (issue 27, point 4),
# rebuilt at 1280x720 and area-downscaled to the analysis size as the pipeline does.

def _analysis(frame: np.ndarray) -> np.ndarray:
    return cv2.resize(frame, (W, H), interpolation=cv2.INTER_AREA)


def _foliage(seed: int, width: int, height: int = 720) -> np.ndarray:
    """Natural-looking ground: multi-scale smooth noise in greens under a paler sky band, strewn
    with leaves and twigs."""
    rng = np.random.default_rng(seed)
    img = np.zeros((height, width, 1), np.float32)
    for cells, amp in ((6, 0.5), (24, 0.3), (90, 0.2), (300, 0.12)):
        n = rng.random((max(2, cells * height // width), cells)).astype(np.float32)
        img += amp * cv2.resize(n, (width, height), interpolation=cv2.INTER_CUBIC)[..., None]
    img = np.float32([60, 110, 50]) * (0.4 + img) * np.linspace(1.3, 0.6, height, dtype=np.float32)[:, None, None]
    img[:height // 5] = img[:height // 5] * 0.5 + np.float32([75, 90, 105])
    img = np.clip(img, 0, 255).astype(np.uint8)
    for _ in range(width * 3):
        c = (int(rng.integers(20, 120)), int(rng.integers(60, 200)), int(rng.integers(10, 90)))
        cv2.ellipse(img, (int(rng.integers(width)), int(rng.integers(height))),
                    (int(rng.integers(4, 16)), int(rng.integers(2, 7))), float(rng.integers(180)), 0, 360, c, -1,
                    cv2.LINE_AA)
    for _ in range(40):
        x, y = int(rng.integers(width)), int(rng.integers(height))
        cv2.line(img, (x, y), (x + int(rng.integers(-60, 60)), y + int(rng.integers(-60, 60))), (50, 40, 30),
                 int(rng.integers(1, 4)), cv2.LINE_AA)
    return img


def test_caption_burned_into_slowly_drifting_nature_footage():
    # A slow drift over foliage (0.3 px per frame at 720p) with a white, dark-rimmed subtitle
    # line: the old filter averaged frames to blur the scene away and found nothing (text_area
    # 0.0) because the slow scene stays as crisp as the caption; the detector reads the line.
    big = _foliage(0, 1280 + 47)
    lines = ("the river runs down to the valley", "where the old mill still stands")
    frames = []
    for t in range(T):
        dy = 5 + int(3 * np.sin(t / 7))
        f = np.ascontiguousarray(np.pad(big, ((10, 10), (0, 0), (0, 0)), mode="edge")[dy:dy + 720,
                                 int(0.3 * t):int(0.3 * t) + 1280])
        text = lines[t * 2 // T]
        (tw, _), _ = cv2.getTextSize(text, FONT, 1.3, 3)
        cv2.putText(f, text, ((1280 - tw) // 2, 648), FONT, 1.3, (0, 0, 0), 8, cv2.LINE_AA)
        cv2.putText(f, text, ((1280 - tw) // 2, 648), FONT, 1.3, (255, 255, 255), 3, cv2.LINE_AA)
        frames.append(_analysis(f))
    verdict = judge(np.stack(frames), TIMES, OverlayTextConfig())
    assert verdict.reason == "overlay_text", verdict.scores


def test_person_in_front_of_a_bookshelf_is_not_overlay_text():
    # Dark book spines with light titles behind a person, a hand-held camera trembling a few
    # pixels: scene text everywhere, none of it burned in.
    rng = np.random.default_rng(0)
    m = 60
    shelf = np.full((720 + 2 * m, 1280 + 2 * m, 3), (90, 60, 40), np.uint8)
    rows = np.linspace(0, 720 + 2 * m, 5).astype(int)
    for r0, r1 in zip(rows[:-1], rows[1:]):
        cv2.rectangle(shelf, (0, r1 - 14), (1280 + 2 * m, r1), (60, 40, 25), -1)
        x = 0
        while x < 1280 + 2 * m:
            bw, top = int(rng.integers(18, 45)), r0 + int(rng.integers(5, 40))
            cv2.rectangle(shelf, (x, top), (x + bw - 2, r1 - 14), tuple(int(v) for v in rng.integers(30, 90, 3)), -1)
            for k in range(int(rng.integers(1, 4))):
                yy = top + 25 + k * int(rng.integers(30, 60))
                if yy + 8 < r1 - 20:
                    cv2.putText(shelf, "".join(rng.choice(list("ABCDEFGHKLMNOPRST"), 2)), (x + 2, yy), FONT, 1.1,
                                (240, 230, 200), 2, cv2.LINE_AA)
                    cv2.line(shelf, (x + 3, yy + 6), (x + bw - 6, yy + 6), (240, 230, 200), 1)
            x += bw
    phase = rng.random(4) * 2 * np.pi
    frames = []
    for t in range(T):
        s = t / FPS
        dx = m + 2 * (np.sin(2 * np.pi * 1.3 * s + phase[0]) + 0.5 * np.sin(2 * np.pi * 2.9 * s + phase[1]))
        dy = m + 2 * (np.sin(2 * np.pi * 1.1 * s + phase[2]) + 0.5 * np.sin(2 * np.pi * 3.3 * s + phase[3]))
        f = cv2.warpAffine(shelf, np.float32([[1, 0, -dx], [0, 1, -dy]]), (1280, 720), flags=cv2.INTER_LINEAR)
        cx = 640 + int(40 * np.sin(t / 15))
        cv2.ellipse(f, (cx, 720), (300, 260), 0, 180, 360, (40, 50, 90), -1, cv2.LINE_AA)
        cv2.ellipse(f, (cx, 324), (110, 140), 0, 0, 360, (170, 130, 110), -1, cv2.LINE_AA)
        cv2.ellipse(f, (cx, 234), (115, 70), 0, 180, 360, (40, 30, 25), -1, cv2.LINE_AA)
        frames.append(_analysis(f))
    verdict = judge(np.stack(frames), TIMES, OverlayTextConfig())
    assert verdict.keep and verdict.scores["text_area"] == 0.0, verdict.scores


@pytest.mark.xfail(strict=True, raises=AssertionError,
                   reason="open: at 2x the detector sees nothing of these lines on the middle sample, "
                   "so the closer look at 3x (which reads both lines) is never taken; searching every band at 3x "
                   "would cost about 2.25x the detector time")
def test_small_caption_on_a_confetti_ground():
    # Discs of the caption glyphs' own size strewn over the picture (bench/overlay_text_cost.py's
    # ground, 3 s instead of 10): there the middle sample shows fragments at 2x and the closer
    # look at 3x reads the lines; here it shows none.
    rng = np.random.default_rng(0)
    width = 1280 + 2 * T
    big = cv2.resize(rng.random((60, width // 8, 3)).astype(np.float32), (width, 720), interpolation=cv2.INTER_CUBIC)
    big = np.clip(big * 170 + 40, 0, 255).astype(np.uint8)
    for _ in range(width // 2):
        c = tuple(int(v) for v in rng.integers(20, 235, 3))
        cv2.circle(big, (int(rng.integers(width)), int(rng.integers(720))), int(rng.integers(8, 40)), c, -1)
    lines = ["we walked down to the old harbour", "and the boats were already gone"]
    frames = []
    for t in range(T):
        f = big[:, 2 * t:2 * t + 1280].copy()
        for row, text in enumerate((lines[(t // 45) % 2], lines[(t // 45 + 1) % 2])):
            (tw, _), _ = cv2.getTextSize(text, FONT, 1.4, 3)
            cv2.putText(f, text, ((1280 - tw) // 2, 620 + 55 * row), FONT, 1.4, (0, 0, 0), 8, cv2.LINE_AA)
            cv2.putText(f, text, ((1280 - tw) // 2, 620 + 55 * row), FONT, 1.4, (255, 255, 230), 3, cv2.LINE_AA)
        frames.append(_analysis(f))
    frames = np.stack(frames)
    assert judge(frames, TIMES, OverlayTextConfig()).reason == "overlay_text"
