"""The fast analysis decode (``skip_unreferenced``) must not cost a cut: where the reference
frames suggest a boundary, the splitter has the frames between them decoded exactly."""

from __future__ import annotations

from fractions import Fraction

import av
import numpy as np
import pytest

from tasks.curate.decode import AnalysisConfig, analysis_frames
from tasks.curate.exact import ExactFrames
from tasks.curate.scenes import SceneConfig, scenes_of
from tasks.video import is_reference, nal_length_size
from tests.tasks.curate.test_scenes import H, W, shot

FPS = 25


def write_bframes(path, frames) -> None:
    """H.264 with three B-frames between references and no B-pyramid: every B-frame is a
    non-reference frame; no scene-cut key frames, so a cut lands wherever the plan puts it."""
    with av.open(str(path), "w") as out:
        stream = out.add_stream("libx264", rate=FPS)
        stream.width, stream.height, stream.pix_fmt = W, H, "yuv420p"
        stream.time_base = Fraction(1, FPS)
        stream.options = {"preset": "veryfast", "crf": "16",
                          "x264-params": "bframes=3:b-pyramid=none:b-adapt=0:scenecut=0:keyint=300:min-keyint=300"}
        for k, image in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(image, format="rgb24")
            frame.pts = k
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode(None):
            out.mux(packet)


def non_reference(path) -> set[int]:
    """Frame indices (presentation order) whose packets no other frame predicts from."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        size = nal_length_size(stream)
        packets = [(p.pts, is_reference(p, size)) for p in container.demux(stream) if p.size]
    order = {pts: i for i, pts in enumerate(sorted(pts for pts, _ in packets))}
    return {order[pts] for pts, ref in packets if not ref}


@pytest.fixture(scope="module")
def cut_on_b_frame(tmp_path_factory):
    """Two panning shots joined by a hard cut at frame 62 (a B-frame between references 60 and 64)."""
    first, second = shot(0, 0.8), shot(3, 1.4)
    cut = 62
    frames = [next(first) for _ in range(cut)] + [next(second) for _ in range(120 - cut)]
    path = tmp_path_factory.mktemp("exact") / "cut_on_b.mp4"
    write_bframes(path, [np.clip(f, 0, 255).astype(np.uint8) for f in frames])
    return path, cut


def test_the_cut_frame_is_left_out_by_the_fast_decode(cut_on_b_frame):
    path, cut = cut_on_b_frame
    assert {cut - 1, cut} <= non_reference(path)
    decoded = {f.index for f in analysis_frames(path)}
    assert cut not in decoded and cut - 1 not in decoded


def test_fast_decode_finds_the_cut_on_its_exact_frame(cut_on_b_frame):
    path, cut = cut_on_b_frame
    fast = [s for s in scenes_of(path, SceneConfig(min_scene_s=0.5), keep_frames=True)]
    full = list(scenes_of(path, SceneConfig(min_scene_s=0.5), AnalysisConfig(skip_unreferenced=False)))
    starts = [s.start_frame for s in fast if s.cause == "cut"]
    assert starts == [cut] == [s.start_frame for s in full if s.cause == "cut"]
    # The frames decoded on demand are in the spans, exactly as a full decode makes them.
    every = {f.index: f.image for f in analysis_frames(path, AnalysisConfig(skip_unreferenced=False))}
    after = next(s for s in fast if s.cause == "cut")
    assert after.indices[0] == cut
    assert np.array_equal(after.frames[0], every[cut])


def test_exact_frames_in_increasing_order_equal_the_full_decode(cut_on_b_frame):
    path, _ = cut_on_b_frame
    every = {f.index: f.image for f in analysis_frames(path, AnalysisConfig(skip_unreferenced=False))}
    exact = ExactFrames(path)
    try:
        # Nearby requests continue forward; a frame whose packet the reader already passed
        # (the reorder delay runs packets ahead of frames) must still come back.
        for wanted in ([5], [9], [10, 11], [61, 62, 63], [63], [2], [117, 118, 119]):
            got = exact.get(wanted)
            assert sorted(got) == sorted(wanted)
            assert all(np.array_equal(got[i], every[i]) for i in wanted)
    finally:
        exact.close()
