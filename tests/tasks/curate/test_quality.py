"""Quality filter on synthetic footage: a textured plane panned under the camera, then
blurred, over- or under-exposed, or given fresh sensor noise per frame."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tasks.curate import quality
from tasks.curate.filter_base import active_box, sample_indices
from tasks.curate.quality import QualityConfig, judge, temporal_noise

H, W, FPS, T = 144, 256, 30.0, 60
TIMES = np.arange(T) / FPS


def scene(seed: int = 0, speed: float = 1.5) -> np.ndarray:
    """T x H x W x 3 frames of a pan over smooth texture with crisp-edged discs."""
    rng = np.random.default_rng(seed)
    big = cv2.resize(rng.random((20, 50, 3)).astype(np.float32), (W + 200, H), interpolation=cv2.INTER_CUBIC)
    big = np.clip(big * 160 + 50, 0, 255).astype(np.uint8)
    for _ in range(120):
        c = tuple(int(v) for v in rng.integers(20, 235, 3))
        cv2.circle(big, (int(rng.integers(W + 200)), int(rng.integers(H))), int(rng.integers(3, 14)), c, -1)
    return np.stack([big[:, int(i * speed):int(i * speed) + W] for i in range(T)])


def noisy(frames: np.ndarray, sigma: float, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(frames + rng.normal(0, sigma, frames.shape), 0, 255).astype(np.uint8)


def test_clean_footage_is_kept():
    verdict = judge(scene(), TIMES, QualityConfig())
    assert verdict.keep, verdict.scores
    assert verdict.scores["sharpness"] > 0.4 and verdict.scores["noise"] < 0.6
    assert verdict.tags == ("exposure:normal",)


@pytest.mark.parametrize("sigma", [2.0, 3.0])
def test_blur_is_rejected(sigma):
    frames = np.stack([cv2.GaussianBlur(f, (0, 0), sigma) for f in scene()])
    verdict = judge(frames, TIMES, QualityConfig())
    assert verdict.reason == "blur", verdict.scores


def test_low_texture_clean_footage_is_not_called_blurry():
    # A plain wall with a few crisp objects: little high-frequency energy, but sharp edges.
    frames = np.empty((T, H, W, 3), np.uint8)
    for t in range(T):
        frames[t] = (118, 121, 125)
        cv2.rectangle(frames[t], (40 + t, 30), (90 + t, 100), (60, 60, 70), -1)
        cv2.circle(frames[t], (180, 70 + t % 20), 15, (200, 190, 120), -1)
    verdict = judge(frames, TIMES, QualityConfig())
    assert verdict.keep, verdict.scores


def test_exposure():
    frames = scene().astype(np.float32)
    over = np.clip(frames * 2.2 + 40, 0, 255).astype(np.uint8)
    under = np.clip(frames * 0.12, 0, 255).astype(np.uint8)
    assert judge(over, TIMES, QualityConfig()).reason == "overexposed"
    assert judge(under, TIMES, QualityConfig()).reason == "underexposed"


def test_drawn_pages_are_not_judged_for_exposure():
    # A white slide and a dark slide: bright or dark by design, not badly exposed.
    for bg, ink in (((250, 250, 250), (20, 20, 20)), ((25, 30, 50), (235, 235, 235))):
        frames = np.empty((T, H, W, 3), np.uint8)
        frames[:] = bg
        for t in range(T):
            cv2.putText(frames[t], "Roadmap", (20, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.7, ink, 2)
            cv2.putText(frames[t], "- first point here", (30, 70), cv2.FONT_HERSHEY_SIMPLEX, 0.45, ink, 1)
        verdict = judge(frames, TIMES, QualityConfig())
        assert verdict.reason not in ("overexposed", "underexposed"), verdict.scores


def test_letterbox_bars_are_not_underexposure():
    frames = np.zeros((T, H, W, 3), np.uint8)
    frames[:, 18:126] = scene()[:, 18:126]
    assert judge(frames, TIMES, QualityConfig()).keep


def test_sensor_noise_is_rejected_but_fine_texture_is_not():
    assert judge(noisy(scene(), 8.0), TIMES, QualityConfig()).reason == "noise"
    # Fine static-pattern texture (sand-like grain that moves with the camera) is not noise.
    rng = np.random.default_rng(4)
    grain = np.clip(rng.normal(128, 30, (H, W + 200, 1)).repeat(3, axis=2), 0, 255).astype(np.uint8)
    frames = np.stack([grain[:, i:i + W] for i in range(T)])
    verdict = judge(frames, TIMES, QualityConfig())
    assert verdict.reason != "noise", verdict.scores


@pytest.mark.parametrize("sigma", [2.0, 5.0])
def test_temporal_noise_estimates_sigma(sigma):
    frames = noisy(scene(), sigma)
    grey = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames[:2]]
    # Grey conversion averages three channels of independent noise: sigma / sqrt(~2.3).
    expected = sigma * np.sqrt(0.299**2 + 0.587**2 + 0.114**2)
    assert temporal_noise(*grey) == pytest.approx(expected, rel=0.35)


def test_white_slide_with_anti_aliased_text_is_the_video_type_filters_call():
    # Anti-aliased text and codec ringing widen a white slide's palette past drawn_palette (the
    # corpus's H.264 slides reached 9-10 colours), so the palette alone would judge it as a
    # blown-out shot; the video-type filter's page rule says it is drawn.
    frames = np.empty((T, H, W, 3), np.uint8)
    for t in range(T):
        frames[t] = 245
        cv2.putText(frames[t], "Safety Budget Design", (14, 24), cv2.FONT_HERSHEY_DUPLEX, 0.6, (20, 20, 30), 1, cv2.LINE_AA)
        for j in range(4):
            cv2.putText(frames[t], "robot pipeline review data", (30, 56 + 20 * j), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                        (20, 20, 30), 1, cv2.LINE_AA)
        ok, buf = cv2.imencode(".jpg", frames[t], [cv2.IMWRITE_JPEG_QUALITY, 90])
        frames[t] = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    verdict = judge(frames, TIMES, QualityConfig())
    # The case the palette alone gets wrong: bright enough to call overexposed, palette too wide.
    assert verdict.scores["palette"] > QualityConfig().drawn_palette
    assert verdict.scores["luma_mean"] >= QualityConfig().overexposed_mean
    assert verdict.keep, verdict.scores


def test_washed_out_footage_is_overexposed_but_bright_footage_with_shadows_is_not():
    # Blacks lifted to light grey with almost nothing clipped: the mean stays under
    # overexposed_mean, but not one pixel is dark (the corpus's 2.4 x + 70 on a dim shot).
    frames = scene().astype(np.float32)
    washed = np.clip(frames * 0.5 + 130, 0, 255).astype(np.uint8)
    verdict = judge(washed, TIMES, QualityConfig())
    assert verdict.scores["luma_mean"] < QualityConfig().overexposed_mean and verdict.scores["clip_high"] < 0.05
    assert verdict.reason == "overexposed", verdict.scores
    # Bright on average (above washed_mean), but with its shadows kept: well exposed.
    bright = np.clip(frames * 1.15 + 20, 0, 255).astype(np.uint8)
    verdict = judge(bright, TIMES, QualityConfig())
    assert verdict.scores["luma_mean"] >= QualityConfig().washed_mean
    assert verdict.keep, verdict.scores


def test_exposure_scores_equal_numpy_statistics_of_the_sampled_greys(real_frames):
    # The filter takes them from a grey-level histogram; the reference stacks and sorts.
    config = QualityConfig()
    scenes = [scene(), np.clip(scene().astype(int) + 90, 0, 255).astype(np.uint8)]
    scenes += [f[:60] for f in real_frames.values()]
    for frames in scenes:
        times = np.arange(len(frames)) / FPS
        picked = frames[sample_indices(len(frames), config.n_samples)]
        top, bottom, left, right = active_box(picked)
        luma = np.stack([cv2.cvtColor(f[top:bottom, left:right], cv2.COLOR_RGB2GRAY) for f in picked])
        moving = float(np.median((np.abs(np.diff(luma.astype(np.int16), axis=0)) > 6).mean(axis=(1, 2))))
        reference = {"luma_mean": float(luma.mean()), "luma_p99": float(np.percentile(luma, 99)),
                     "luma_p01": float(np.percentile(luma, 1)), "clip_high": float((luma >= 250).mean()),
                     "clip_low": float((luma <= 5).mean()), "luma_change": moving}
        scores = judge(frames, times, config).scores
        assert {k: scores[k] for k in reference} == reference


def test_the_video_type_pass_is_asked_only_when_exposure_would_reject(monkeypatch):
    asked = []
    monkeypatch.setattr(quality, "looks_drawn", lambda frames, times: asked.append(1) or False)
    assert judge(scene(), TIMES, QualityConfig()).keep and not asked  # normal exposure: never asked
    dark = (scene() * 0.2).astype(np.uint8)
    assert judge(dark, TIMES, QualityConfig()).reason == "underexposed" and len(asked) == 1


def test_a_moving_picture_that_stops_dead_is_frozen_but_a_quiet_fixed_shot_or_repeated_frames_are_not():
    moving = scene(speed=3.0)
    frozen = moving.copy()
    frozen[25:45] = frozen[25]  # the decoder holds one frame for 2/3 s
    verdict = judge(frozen, TIMES, QualityConfig())
    assert verdict.reason == "frozen", verdict.scores
    assert verdict.scores["frozen_s"] == pytest.approx(19 / FPS)  # from frame 25 to frame 44
    # Every 7th frame repeated (as some encoders do): never long enough.
    repeated = moving.copy()
    repeated[7::7] = repeated[6:-1:7]
    assert judge(repeated, TIMES, QualityConfig()).keep
    # A fixed camera on a quiet scene repeats frames exactly for a second, then a little moves.
    quiet = np.repeat(scene()[:1], T, axis=0)
    for t in range(30, T):
        cv2.circle(quiet[t], (40 + t, 60), 6, (240, 240, 240), -1)
    verdict = judge(quiet, TIMES, QualityConfig())
    assert verdict.keep and verdict.scores["frozen_s"] >= 0.9, verdict.scores


def test_real_decoder_freeze_is_found():
    from tasks.curate.decode import analysis_frames
    from tests.support import SHARED_DATA

    path = SHARED_DATA / "videos-dev" / "armwrestle.mp4"
    if not path.is_file():
        pytest.skip("../shared/data is absent")
    decoded = [f for f in analysis_frames(path) if 200 <= f.index < 280]
    frames, times = np.stack([f.image for f in decoded]), np.array([f.time for f in decoded])
    verdict = judge(frames, times, QualityConfig())
    assert verdict.reason == "smeared" and verdict.scores["smeared_frames"] == 1  # the concealment at 229 ...
    assert verdict.scores["frozen_s"] >= 1.0  # ... then frames 231-267 repeat it
    after = [k for k, f in enumerate(decoded) if f.index >= 231]
    assert judge(frames[after], times[after], QualityConfig()).reason == "frozen"
    hikers = [f for f in analysis_frames(SHARED_DATA / "videos-dev" / "hikers.mp4")]
    assert judge(np.stack([f.image for f in hikers]), np.array([f.time for f in hikers]), QualityConfig()).keep
