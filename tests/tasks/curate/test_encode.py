"""Clip encoding: exact frames after seeks, one pass for many spans, reproducible bytes, display
orientation and even sizes."""

from __future__ import annotations

import av
import numpy as np
import pytest

import tasks.curate.encode as encode
from tasks.curate.decode import AnalysisConfig, analysis_frames
from tasks.curate.encode import encode_clip, encode_clips
from tasks.video import EncodeConfig, probe
from tests.support import coded, read_index


def clip_frames(path) -> list[np.ndarray]:
    with av.open(str(path)) as container:
        return [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]


@pytest.fixture(scope="module")
def source(make_video):
    """200 frames at 25 fps, a key frame every 25 frames."""
    return make_video((coded(i) for i in range(200)), fps=25, gop=25)


def test_spans_get_exactly_their_frames_in_one_pass(source, tmp_path, monkeypatch):
    decoded = []
    original = encode._frames

    def counting(container, stream, idle=None):
        for frame in original(container, stream, idle):
            decoded.append(frame.pts)
            yield frame

    monkeypatch.setattr(encode, "_frames", counting)
    spans = [(160, 170), (3, 20), (150, 163), (20, 30)]
    paths = [tmp_path / f"clip_{j}.mp4" for j in range(len(spans))]
    clips = encode_clips(source, spans, paths)
    for (start, end), clip, path in zip(spans, clips, paths, strict=True):
        assert clip.path == path and path.exists()
        assert (clip.start_frame, clip.end_frame, clip.frames) == (start, end, end - start)
        assert [read_index(f) for f in clip_frames(path)] == list(range(start, end))
        assert (clip.width, clip.height) == (64, 48) and clip.bytes == path.stat().st_size
    # Frames 0..29 then a seek to the key frame at 150: far fewer than 170 decodes.
    assert len(decoded) < 30 + 25 + 10, len(decoded)
    assert not list(tmp_path.glob(".*tmp"))


def test_bytes_are_reproducible(source, tmp_path):
    first = encode_clip(source, 40, 90, tmp_path / "a.mp4")
    for name in ("b.mp4", "c.mp4", "d.mp4"):
        # Fresh heap garbage between runs: uninitialised reads in the encoder would show.
        _garbage = [np.random.default_rng().integers(0, 256, 1 << 20, dtype=np.uint8) for _ in range(4)]
        again = encode_clip(source, 40, 90, tmp_path / name, EncodeConfig())
        assert again.sha256 == first.sha256
        assert (tmp_path / name).read_bytes() == (tmp_path / "a.mp4").read_bytes()
    other = encode_clip(source, 40, 90, tmp_path / "e.mp4", EncodeConfig(crf=30))
    assert other.sha256 != first.sha256


def test_clip_is_in_display_orientation_with_square_pixels(make_video, tmp_path):
    rotated = make_video((coded(i) for i in range(30)), rotation=90)
    clip = encode_clip(rotated, 5, 15, tmp_path / "rotated.mp4")
    info = probe(clip.path)
    assert (clip.width, clip.height) == (48, 64) and info.rotation == 0
    analysis = list(analysis_frames(rotated, AnalysisConfig(long_side=64, skip_unreferenced=False)))[5]
    first = clip_frames(clip.path)[0]
    assert np.abs(first.astype(int) - analysis.image.astype(int)).mean() < 4
    assert read_index(np.rot90(first, k=-1)) == 5

    stretched = make_video((coded(i) for i in range(30)), sar=(3, 2))
    clip = encode_clip(stretched, 0, 10, tmp_path / "stretched.mp4")
    assert (clip.width, clip.height) == (96, 48) and probe(clip.path).sar == 1.0


def test_odd_sizes_become_even(make_video, tmp_path):
    odd = make_video((coded(i, 63, 47) for i in range(20)))
    clip = encode_clip(odd, 2, 12, tmp_path / "odd.mp4")
    assert (clip.width, clip.height) == (62, 46)
    assert [read_index(f) for f in clip_frames(clip.path)] == list(range(2, 12))


def test_variable_frame_rate_keeps_its_timing(make_video, tmp_path):
    times = np.cumsum([0.0] + [0.02 if i % 2 else 0.06 for i in range(39)])
    path = make_video((coded(i) for i in range(40)), times=times)
    clip = encode_clip(path, 10, 30, tmp_path / "vfr.mp4")
    got = [f.time for f in analysis_frames(clip.path, AnalysisConfig(skip_unreferenced=False))]
    np.testing.assert_allclose(np.array(got) - got[0], times[10:30] - times[10], atol=2e-3)


def test_bad_spans_are_refused_before_writing(source, tmp_path):
    with pytest.raises(ValueError, match="outside frames"):
        encode_clip(source, 190, 210, tmp_path / "late.mp4")
    with pytest.raises(ValueError, match=str(source)):
        encode_clips(source, [(5, 5)], [tmp_path / "empty.mp4"])
    with pytest.raises(ValueError, match="output paths"):
        encode_clips(source, [(0, 5)], [])
    assert not list(tmp_path.iterdir())


def test_frames_left_undecoded_on_the_way_change_no_byte(source, tmp_path, monkeypatch):
    """Unreferenced frames before and between spans are not decoded; the clips are the bytes of
    a pass that decodes every frame."""
    spans = [(60, 80), (88, 95), (130, 140)]  # lead-ins from the key frames at 50 and 125, a gap of 8
    decoded = {}
    original = encode._frames

    def counting(container, stream, idle=None):
        for frame in original(container, stream, idle):
            decoded[idle is None] = decoded.get(idle is None, 0) + 1
            yield frame

    monkeypatch.setattr(encode, "_frames", counting)
    fast = encode_clips(source, spans, [tmp_path / f"fast_{j}.mp4" for j in range(len(spans))])
    monkeypatch.setattr(encode, "_idle", lambda *args: None)
    full = encode_clips(source, spans, [tmp_path / f"full_{j}.mp4" for j in range(len(spans))])
    assert [c.sha256 for c in fast] == [c.sha256 for c in full]
    assert [c.frames for c in fast] == [20, 7, 10]
    assert decoded[False] < decoded[True], decoded
