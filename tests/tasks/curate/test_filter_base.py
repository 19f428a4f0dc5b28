"""The filter contract and its shared helpers: Verdict, check_frames, sampling, the letterbox
crop and the palette, each fast path against its slow reference."""

from __future__ import annotations

import cv2
import numpy as np
import pydantic
import pytest

from tasks.curate.filter_base import Verdict, active_box, check_frames, palette_size, percentiles_of_histogram
from tasks.curate.filter_base import sample_indices

H, W, FPS = 144, 256, 30.0


def scene(n: int, speed: float = 1.5, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """n x H x W x 3 frames panning over a textured plane at ``speed`` px per frame."""
    rng = np.random.default_rng(seed)
    big = cv2.resize(rng.random((20, 60, 3)).astype(np.float32), (W + 600, H + 40), interpolation=cv2.INTER_CUBIC)
    big = np.clip(big * 200 + 30, 0, 255).astype(np.uint8)
    for _ in range(150):
        c = tuple(int(v) for v in rng.integers(0, 255, 3))
        cv2.circle(big, (int(rng.integers(W + 600)), int(rng.integers(H + 40))), int(rng.integers(3, 14)), c, -1)
    frames = np.stack([big[20:20 + H, int(i * speed):int(i * speed) + W] for i in range(n)])
    return frames, np.arange(n) / FPS


def test_verdict_is_frozen_and_strict():
    v = Verdict(keep=False, reason="blur", scores={"sharpness": 0.1}, tags=("exposure:normal",))
    with pytest.raises(pydantic.ValidationError):
        v.keep = True
    with pytest.raises(pydantic.ValidationError):
        Verdict(keep=True, colour="red")


def test_check_frames_names_the_problem():
    frames, times = scene(4)
    with pytest.raises(ValueError, match="uint8"):
        check_frames(frames.astype(np.float32), times)
    with pytest.raises(ValueError, match="T x h x w x 3"):
        check_frames(frames[..., 0], times)
    with pytest.raises(ValueError, match="times"):
        check_frames(frames, times[:3])
    with pytest.raises(ValueError, match="increasing"):
        check_frames(frames, times[::-1].copy())


def test_sample_indices_cover_both_ends():
    assert sample_indices(5, 10).tolist() == [0, 1, 2, 3, 4]
    idx = sample_indices(1000, 8)
    assert len(idx) == 8 and idx[0] == 0 and idx[-1] == 999 and np.all(np.diff(idx) > 0)


def test_active_box_finds_letterbox_bars_but_not_a_dark_scene():
    frames, _ = scene(3)
    boxed = np.zeros_like(frames)
    boxed[:, 20:124, 30:226] = frames[:, 20:124, 30:226]
    assert active_box(boxed) == (20, 124, 30, 226)
    dark = (frames // 12).astype(np.uint8)  # everything below the bar level: not a letterbox
    assert active_box(dark) == (0, H, 0, W)


def test_palette_size_separates_drawn_from_footage():
    frames, _ = scene(1)
    drawn = np.zeros((H, W, 3), np.uint8)
    drawn[:] = (240, 240, 235)
    cv2.rectangle(drawn, (20, 20), (120, 60), (200, 40, 40), -1)
    cv2.putText(drawn, "Quarterly plan", (20, 100), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (30, 30, 30), 1)
    assert palette_size(drawn) <= 4
    assert palette_size(frames[0]) > 30
    # Contrast stretching: a very dark shot keeps its many shades.
    assert palette_size((frames[0] // 8).astype(np.uint8)) > 30


# Slow, obvious references of the fast paths in filter_base.py (sorting, reducing over the channel
# axis), as the filters computed them before the fast paths replaced them.
def palette_size_reference(frame: np.ndarray, cover: float = 0.95) -> float:
    lum = frame.max(axis=2).astype(np.int16) + frame.min(axis=2)
    unclipped = (lum > 12) & (lum < 498)
    if unclipped.mean() >= 0.1:
        frame = frame[unclipped][None]
    lo, hi = np.percentile(frame, (1, 99))
    stretched = np.clip((frame.astype(np.float32) - lo) * (255.0 / max(16.0, hi - lo)), 0, 255).astype(np.uint8)
    q = (stretched >> 4).astype(np.int32)
    counts = np.bincount(((q[..., 0] << 8) | (q[..., 1] << 4) | q[..., 2]).ravel(), minlength=4096)
    total = np.cumsum(np.sort(counts)[::-1])
    return float(np.searchsorted(total, cover * total[-1]) + 1)


def active_box_reference(frames: np.ndarray, dark: int = 24) -> tuple[int, int, int, int]:
    peak = frames.max(axis=(0, 3))
    h, w = peak.shape
    rows = np.flatnonzero(np.percentile(peak, 98, axis=1) >= dark)
    cols = np.flatnonzero(np.percentile(peak, 98, axis=0) >= dark)
    if rows.size == 0 or cols.size == 0:
        return 0, h, 0, w
    top, bottom, left, right = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    if (bottom - top) < h // 2 or (right - left) < w // 2:
        return 0, h, 0, w
    return top, bottom, left, right


def odd_frames() -> list[np.ndarray]:
    """Frames that stress the edge cases: black, white, mostly clipped, tiny, a strided crop."""
    frames, _ = scene(2)
    rng = np.random.default_rng(3)
    blown = frames[0].copy()
    blown[:, 40:] = 255
    return [np.zeros((16, 16, 3), np.uint8), np.full((16, 20, 3), 255, np.uint8), blown,
            rng.integers(0, 256, (17, 31, 3), dtype=np.uint8), (frames[1] // 40).astype(np.uint8),
            frames[1][5:120, 9:200], np.clip(frames[0].astype(int) * 3, 0, 255).astype(np.uint8)]


def test_palette_size_equals_the_sorting_reference(real_frames):
    pictures = odd_frames() + [f for frames in real_frames.values() for f in frames[::10]]
    assert len(pictures) > 100
    for frame in pictures:
        assert palette_size(frame) == palette_size_reference(frame)


def test_percentiles_of_histogram_are_numpys_bit_for_bit():
    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 7, 100, 1001, 40000):
        for _ in range(20):
            values = rng.integers(0, 256, n) if n < 1000 else rng.normal(128, 30, n).clip(0, 255).astype(int)
            qs = (0, 1, 37.5, 50, 98, 99, 100)
            fast = percentiles_of_histogram(np.bincount(values, minlength=256), qs)
            assert [float(v) for v in fast] == np.percentile(values, qs).tolist()
            assert float(percentiles_of_histogram(np.bincount(values), (99,))[0]) == float(np.percentile(values, 99))


def test_active_box_equals_the_reference(real_frames):
    stacks = [f[i:i + 12] for f in real_frames.values() for i in range(0, len(f) - 12, 40)]
    frames, _ = scene(12)
    for top, bottom, left, right in ((20, 124, 30, 226), (0, 144, 40, 216), (10, 144, 0, 256)):
        boxed = np.zeros_like(frames)
        boxed[:, top:bottom, left:right] = frames[:, top:bottom, left:right]
        stacks.append(boxed)
    for stack in stacks + [np.stack([f] * 2) for f in odd_frames()]:
        assert active_box(stack) == active_box_reference(stack)


def test_a_judged_once_verdict_is_kept_for_one_scene_only():
    from tasks.curate.filter_base import judged_once, one_scene

    calls = []

    @judged_once
    def judge(frames, times, config):
        calls.append(config)
        return Verdict(keep=True, scores={"n": float(len(calls))})

    frames, times = scene(4)
    with one_scene():
        first = judge(frames, times, "a")
        assert judge(frames, times, "a") is first  # same arrays, equal config: the first verdict
        judge(frames, times, "b")  # another config
        judge(frames.copy(), times, "a")  # other arrays, even with the same pixels
        assert len(calls) == 3
    judge(frames, times, "a")  # outside a scene nothing is kept
    judge(frames, times, "a")
    assert len(calls) == 5


def test_the_filters_ask_the_video_type_rules_once_a_scene():
    from unittest import mock

    from tasks.curate import video_type
    from tasks.curate.filters import run_filters

    frames, times = scene(40, speed=0.0)  # still: motion and quality both ask whether it is drawn
    with mock.patch.object(video_type, "frame_features", wraps=video_type.frame_features) as measured:
        merged, _ = run_filters(frames, times)
    samples = len(sample_indices(len(frames), video_type.VideoTypeConfig().n_samples))
    assert measured.call_count == samples
    assert merged.reason == "static"
