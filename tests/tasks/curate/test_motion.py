"""Motion filter on synthetic camera paths over a textured plane (each frame is a crop at a
known offset, so the true camera motion is exact)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tasks.curate.filter_base import grey
from tasks.curate.motion import MotionConfig, judge, zoom_rate
from tests.support import SHARED_DATA as SHARED

H, W, FPS, T = 144, 256, 30.0, 90


def plane(seed: int = 0, margin: int = 120) -> np.ndarray:
    """(H + 2 margin) x (W + 2 margin) x 3 uint8 texture with blobs and sharp edges."""
    rng = np.random.default_rng(seed)
    h, w = H + 2 * margin, W + 2 * margin
    img = cv2.resize(rng.random((h // 16, w // 16, 3)).astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
    img = np.clip(img * 200 + 30, 0, 255).astype(np.uint8)
    for _ in range(60):
        c = tuple(int(v) for v in rng.integers(0, 255, 3))
        cv2.circle(img, (int(rng.integers(w)), int(rng.integers(h))), int(rng.integers(3, 20)), c, -1)
    return img


def crops(path: np.ndarray, seed: int = 0, noise: float = 0.0) -> np.ndarray:
    """T x H x W x 3 frames: crop of the plane at sub-pixel offsets path[t] = (x, y)."""
    big = plane(seed)
    rng = np.random.default_rng(seed + 1)
    out = np.empty((len(path), H, W, 3), np.uint8)
    for t, (x, y) in enumerate(path):
        m = np.float32([[1, 0, -(120 + x)], [0, 1, -(120 + y)]])
        frame = cv2.warpAffine(big, m, (W, H), flags=cv2.INTER_LINEAR).astype(np.float32)
        out[t] = np.clip(frame + rng.normal(0, noise, frame.shape), 0, 255) if noise else frame
    return out


TIMES = np.arange(T) / FPS
STEADY = np.zeros((T, 2))
PAN = np.stack([np.arange(T) * 1.5, np.zeros(T)], axis=1)  # content moves left: camera pans right
SHAKE = np.random.default_rng(3).normal(0, 4.0, (T, 2))


def test_static_is_rejected_even_with_sensor_noise():
    for noise in (0.0, 6.0):
        verdict = judge(crops(STEADY, noise=noise), TIMES, MotionConfig())
        assert verdict.reason == "static", (noise, verdict.scores)
        assert verdict.scores["moving_fraction"] <= 0.001


def test_a_picture_too_dark_to_see_motion_in_is_not_called_static():
    # A slow pan at a tenth of the exposure: a 1-px move changes almost no pixel by more than
    # the moving threshold, so stillness cannot be seen (corpus underexposed segments).
    slow = np.stack([np.arange(T) * 0.1, np.zeros(T)], axis=1)
    dark = (crops(slow).astype(np.float32) * 0.04).astype(np.uint8)
    verdict = judge(dark, TIMES, MotionConfig())
    assert verdict.scores["motion_visible"] < MotionConfig().visible_min and verdict.reason != "static", verdict.scores
    # The same dark picture standing still is not static either: it is not judged; the
    # same stillness at full exposure is.
    assert judge(np.repeat(dark[:1], T, axis=0), TIMES, MotionConfig()).reason != "static"
    assert judge(crops(STEADY), TIMES, MotionConfig()).scores["motion_visible"] >= MotionConfig().visible_min


def test_pan_is_kept_and_tagged_with_its_direction():
    verdict = judge(crops(PAN), TIMES, MotionConfig())
    assert verdict.keep, verdict.scores
    assert "camera:pan_right" in verdict.tags
    # 1.5 px per frame at 30 fps over a 256 px long side.
    assert verdict.scores["motion_global"] == pytest.approx(1.5 * FPS / W, rel=0.2)
    assert verdict.scores["shake"] < 0.3
    flipped = judge(crops(-PAN[:, ::-1]), TIMES, MotionConfig())
    assert "camera:pan_up" in flipped.tags


def test_shake_is_rejected_but_a_pan_with_local_motion_is_not():
    assert judge(crops(SHAKE), TIMES, MotionConfig()).reason == "shake"
    frames = crops(PAN)
    # A bright object crossing the picture fast: phase correlation may lock on it for a few
    # steps, which must not read as a shaking camera.
    for t in range(30, 45):
        cv2.rectangle(frames[t], (10 + 14 * (t - 30), 20), (90 + 14 * (t - 30), 130), (250, 250, 250), -1)
    verdict = judge(frames, TIMES, MotionConfig())
    assert verdict.keep, verdict.scores


def test_variable_frame_rate_uses_timestamps():
    # Same camera speed in px per second, sampled at irregular times.
    rng = np.random.default_rng(5)
    times = np.cumsum(rng.uniform(0.02, 0.05, T))
    path = np.stack([times * 45.0, np.zeros(T)], axis=1)
    verdict = judge(crops(path), times, MotionConfig())
    assert verdict.keep
    assert verdict.scores["motion_global"] == pytest.approx(45.0 / W, rel=0.2)


def test_zoom_rate_sign_and_tag():
    big = plane(1)
    frames = []
    for t in range(T):
        s = 1.0 + 0.01 * t  # zoom in: 1 % per frame, about 30 % per second
        m = cv2.getRotationMatrix2D((big.shape[1] / 2, big.shape[0] / 2), 0, s)
        frames.append(cv2.warpAffine(big, m, big.shape[1::-1])[120:120 + H, 120:120 + W])
    frames = np.stack(frames)
    a, b = (grey(frames[i], MotionConfig().zoom_size) for i in (10, 16))
    # Six frames apart: scale 1.16 / 1.10, a relative change of about 0.06.
    assert zoom_rate(a, b) == pytest.approx(0.06, rel=0.3)
    assert zoom_rate(b, a) == pytest.approx(-0.06, rel=0.3)
    verdict = judge(frames, TIMES, MotionConfig())
    assert "camera:zoom_in" in verdict.tags
    assert verdict.scores["zoom"] == pytest.approx(np.log(1.01) * FPS, rel=0.5)


def test_disabled_filter_keeps_without_scores():
    verdict = judge(crops(STEADY), TIMES, MotionConfig(enabled=False))
    assert verdict.keep and verdict.scores == {}


def test_a_ticking_counter_or_a_held_slide_is_not_a_static_camera():
    frames = crops(STEADY)
    for t in range(T):  # a small counter changing every frame: 0.3 % of the picture
        cv2.rectangle(frames[t], (100, 60), (160, 75), (0, 0, 0), -1)
        cv2.putText(frames[t], f"{t:04d}", (104, 72), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1)
    verdict = judge(frames, TIMES, MotionConfig())
    assert verdict.keep and verdict.scores["moving_fraction"] > 0.001, verdict.scores
    slide = np.full((T, H, W, 3), 245, np.uint8)
    cv2.putText(slide[0], "Agenda", (20, 40), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (20, 20, 20), 2)
    slide[:] = slide[0]
    held = judge(slide, TIMES, MotionConfig())
    assert held.keep and held.scores["moving_fraction"] == 0.0


def test_a_held_slide_with_codec_ringing_is_left_to_the_video_type_filter():
    # Ringing around anti-aliased text widens the palette past drawn_palette (9-10 colours on
    # the corpus's H.264 slides); the video-type filter's page rule still calls it drawn.
    slide = np.full((H, W, 3), 245, np.uint8)
    cv2.putText(slide, "Safety Budget Design", (14, 24), cv2.FONT_HERSHEY_DUPLEX, 0.6, (20, 20, 30), 1, cv2.LINE_AA)
    for j in range(4):
        cv2.putText(slide, "robot pipeline review data", (30, 56 + 20 * j), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                    (20, 20, 30), 1, cv2.LINE_AA)
    ok, buf = cv2.imencode(".jpg", slide, [cv2.IMWRITE_JPEG_QUALITY, 90])
    frames = np.repeat(cv2.imdecode(buf, cv2.IMREAD_COLOR)[None], T, axis=0)
    verdict = judge(frames, TIMES, MotionConfig())
    assert verdict.scores["moving_fraction"] == 0.0
    assert verdict.keep, verdict.scores
    # The same stillness on camera footage is static.
    assert judge(np.repeat(crops(STEADY)[:1], T, axis=0), TIMES, MotionConfig()).reason == "static"


def test_handheld_sway_and_tremor_is_kept_but_a_whip_pan_is_shake():
    # A hand-held camera: a slow sway of a few px and a 1 px tremor every frame. Integrated
    # frame by frame at 30 fps the tremor once read as shake; sampled at 10 Hz it is small and
    # slow enough. A phone swung back and forth twice a second is not.
    rng = np.random.default_rng(8)
    sway = np.stack([4 * np.sin(2 * np.pi * 0.4 * TIMES), 2 * np.sin(2 * np.pi * 0.3 * TIMES + 1)], axis=1)
    handheld = judge(crops(sway + rng.normal(0, 1.0, (T, 2))), TIMES, MotionConfig())
    assert handheld.keep, handheld.scores
    assert handheld.scores["shake"] < MotionConfig().shake_min / 2
    whip = np.stack([30 * np.sin(2 * np.pi * 2 * TIMES), 5 * np.sin(2 * np.pi * 1.3 * TIMES)], axis=1)
    verdict = judge(crops(whip), TIMES, MotionConfig())
    assert verdict.reason == "shake", verdict.scores
    assert verdict.scores["jitter_amplitude"] > 5  # percent of the long side


def test_shake_does_not_depend_on_the_frame_rate():
    # The same tremor seen at 30 fps and with frames left out, as a decoder that skips
    # unreferenced frames hands them over, measures about the same: every second frame (the
    # 10 Hz samples of the camera path fall 1/15 s and 2/15 s apart), two in three (0.1 s), five
    # in six (5 fps, below jitter_hz: every frame a sample, 0.2 s apart). Steps are timed, not
    # counted or assumed 1/30 s. The tremor (1.2 and 1.7 Hz) is slow enough for 5 fps to see.
    path = np.stack([3 * np.sin(2 * np.pi * 1.2 * TIMES), 2 * np.sin(2 * np.pi * 1.7 * TIMES + 1)], axis=1)
    frames = crops(path)
    full = judge(frames, TIMES, MotionConfig()).scores["shake"]
    assert full > 1
    for every in (2, 3, 6):
        thinned = judge(frames[::every], TIMES[::every], MotionConfig()).scores["shake"]
        assert thinned == pytest.approx(full, rel=0.25), every


@pytest.mark.skipif(not (SHARED / "videos-dev" / "labels.json").is_file(), reason="../shared/data is absent")
@pytest.mark.parametrize("name, shaky", [("videos-dev/hikers.mp4", False), ("videos-dev/pancake.mkv", False),
                                         ("videos-dev/group_vp8.webm", False), ("videos-dev/armwrestle.mp4", True),
                                         ("videos/fire2.mp4", True)])
def test_real_handheld_footage(name, shaky):
    from tasks.curate.decode import analysis_frames

    decoded = list(analysis_frames(SHARED / name))
    frames = np.stack([f.image for f in decoded])
    times = np.array([f.time for f in decoded])
    verdict = judge(frames, times, MotionConfig())
    assert (verdict.reason == "shake") == shaky, verdict.scores
