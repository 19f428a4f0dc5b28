"""The single analysis pass (and frames_at), on tiny generated videos whose frames encode their index."""

from __future__ import annotations

import threading
from pathlib import Path

import av
from av.video.frame import PictureType
import cv2
import numpy as np
import pytest

from tasks.curate.decode import AnalysisConfig, DecodeReport, analysis_frames
from tasks.curate.exact import frames_at
from tasks.video import DecodeError, frame_pts, probe
from tests.support import coded, read_index

DATA = Path(__file__).resolve().parents[3] / "../shared/data/videos"


def test_every_frame_once_in_order_with_pts_times(make_video):
    path = make_video((coded(i) for i in range(50)), fps=25)
    report = DecodeReport()
    frames = list(analysis_frames(path, AnalysisConfig(long_side=64, skip_unreferenced=False), report))
    assert [f.index for f in frames] == list(range(50))
    assert [read_index(f.image) for f in frames] == list(range(50))
    np.testing.assert_allclose([f.time for f in frames], np.arange(50) / 25, atol=1e-6)
    assert frames[0].image.shape == (48, 64, 3) and frames[0].image.dtype == np.uint8
    assert (report.frames, report.skipped, report.decode_errors) == (50, 0, 0)
    pts, keys, _, _ = frame_pts(path)
    assert len(pts) == 50 and keys[0] == pts[0]


def test_downscale_keeps_aspect_and_never_upscales(make_video):
    path = make_video((coded(i, 160, 90) for i in range(5)))
    assert next(iter(analysis_frames(path, AnalysisConfig(long_side=64)))).image.shape == (36, 64, 3)
    assert next(iter(analysis_frames(path, AnalysisConfig(long_side=512)))).image.shape == (90, 160, 3)


def test_variable_frame_rate_times_come_from_timestamps(make_video):
    times = np.cumsum([0.0] + [0.02 if i % 3 else 0.08 for i in range(29)])
    path = make_video((coded(i) for i in range(30)), fps=25, times=times)
    info = probe(path)
    assert info.vfr
    frames = list(analysis_frames(path))
    assert [read_index(f.image) for f in frames] == [f.index for f in frames]
    np.testing.assert_allclose([f.time for f in frames], times[[f.index for f in frames]], atol=1.5e-3)


@pytest.mark.parametrize("rotation", [90, 180, 270])
def test_rotation_metadata_gives_display_orientation(make_video, rotation):
    path = make_video((coded(i) for i in range(10)), rotation=rotation)
    info = probe(path)
    assert info.rotation == rotation
    expected_shape = (64, 48) if rotation in (90, 270) else (48, 64)
    assert (info.display_height, info.display_width) == expected_shape
    frames = list(analysis_frames(path, AnalysisConfig(skip_unreferenced=False)))
    assert frames[3].image.shape[:2] == expected_shape
    # Reference: OpenCV applies the same display matrix when it reads (its FFmpeg backend).
    capture = cv2.VideoCapture(str(path))
    for _ in range(4):
        ok, bgr = capture.read()
    capture.release()
    assert ok and bgr.shape[:2] == expected_shape
    assert np.abs(bgr[..., ::-1].astype(int) - frames[3].image.astype(int)).mean() < 3
    turned_back = np.rot90(frames[3].image, k=-rotation // 90)
    assert read_index(turned_back) == 3


def test_non_square_pixels_are_stretched_to_display_width(make_video):
    path = make_video((coded(i) for i in range(5)), sar=(2, 1))
    info = probe(path)
    assert info.sar == 2.0 and (info.display_width, info.display_height) == (128, 48)
    image = next(iter(analysis_frames(path))).image
    assert image.shape == (48, 128, 3)
    assert read_index(cv2.resize(image, (64, 48), interpolation=cv2.INTER_AREA)) == 0


def test_odd_width_and_height(make_video):
    path = make_video((coded(i, 63, 47) for i in range(12)))
    info = probe(path)
    assert (info.width, info.height) == (63, 47)
    frames = list(analysis_frames(path))
    assert frames[0].image.shape == (47, 63, 3)
    assert [read_index(f.image) for f in frames] == [f.index for f in frames]


def test_corrupt_frames_in_the_middle_are_skipped_and_counted(make_video, tmp_path):
    path = make_video((coded(i) for i in range(60)), gop=20)
    with av.open(str(path)) as container:
        packets = [(p.pos, p.size) for p in container.demux(video=0) if p.size]
    data = bytearray(path.read_bytes())
    rng = np.random.default_rng(0)
    for pos, size in packets[25:28]:  # three frames inside the second group of pictures
        data[pos + 4: pos + size] = rng.integers(0, 256, size - 4, dtype=np.uint8).tobytes()
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(bytes(data))
    report = DecodeReport()
    frames = list(analysis_frames(broken, AnalysisConfig(skip_unreferenced=False), report=report))
    assert report.decode_errors + report.skipped > 0 and report.problems
    assert 40 <= len(frames) < 60
    # Indices stay those of the timestamps: frames after the next key frame are intact.
    assert [read_index(f.image) for f in frames if f.index >= 40] == list(range(40, 60))


def make_bad(kind: str, folder: Path) -> Path:
    path = folder / f"bad_{kind}"
    if kind == "empty":
        path.write_bytes(b"")
    elif kind == "text":
        path.write_text("not a video at all\n" * 50)
    elif kind == "audio":
        with av.open(str(path), "w", format="wav") as container:
            stream = container.add_stream("pcm_s16le", rate=8000)
            frame = av.AudioFrame.from_ndarray(np.zeros((1, 800), np.int16), format="s16", layout="mono")
            frame.sample_rate = 8000
            for packet in [*stream.encode(frame), *stream.encode()]:
                container.mux(packet)
    elif kind == "huge":
        with av.open(str(path), "w", format="nut") as container:
            stream = container.add_stream("rawvideo", rate=25)
            stream.width, stream.height, stream.pix_fmt = 20000, 8, "gray"
            frame = av.VideoFrame.from_ndarray(np.zeros((8, 20000), np.uint8), format="gray")
            for packet in [*stream.encode(frame), *stream.encode()]:
                container.mux(packet)
    elif kind == "fps":
        with av.open(str(path), "w", format="mp4") as container:
            stream = container.add_stream("libx264", rate=5000)
            stream.width, stream.height, stream.pix_fmt = 32, 32, "yuv420p"
            frame = av.VideoFrame.from_ndarray(np.zeros((32, 32, 3), np.uint8), format="rgb24")
            for packet in [*stream.encode(frame), *stream.encode()]:
                container.mux(packet)
    return path


@pytest.mark.parametrize("kind, problem", [
    ("missing", "no such file"), ("empty", "empty file"), ("text", "not a readable video"),
    ("audio", "no video stream"), ("huge", "absurd frame size"), ("fps", "absurd or missing frame rate"),
])
def test_unreadable_input_is_refused_with_file_and_reason(tmp_path, kind, problem):
    path = tmp_path / "bad_missing" if kind == "missing" else make_bad(kind, tmp_path)
    with pytest.raises(DecodeError, match=problem) as caught:
        probe(path)
    assert str(path) in str(caught.value)
    with pytest.raises(DecodeError):
        next(iter(analysis_frames(path)))


def test_real_footage_decodes_fully():
    path = DATA / "bikes.mp4"
    if not path.exists():
        pytest.skip("../shared/data is not present")
    info = probe(path)
    frames = list(analysis_frames(path, AnalysisConfig(skip_unreferenced=False), info=info))
    assert len(frames) == info.n_frames == 250
    assert frames[0].image.shape == (109, 256, 3)
    report = DecodeReport()
    assert len(list(analysis_frames(path, info=info, report=report))) == 135  # as FFmpeg's skip_frame NONREF
    assert (report.unreferenced, report.missing) == (115, 0)


def test_packed_b_frames_are_frames_not_corruption():
    """MPEG-4 Part 2 in AVI with packed B-frames: the decoder stamps its output 1, 2, 4, 3, ...;
    every frame is a good frame, in the decoder's order, with increasing times."""
    path = DATA.parent / "videos-dev" / "makeup_webcam.avi"
    if not path.exists():
        pytest.skip("../shared/data is not present")
    report = DecodeReport()
    frames = list(analysis_frames(path, report=report))
    assert (len(frames), report.missing, report.corrupt, report.problems) == (164, 0, 0, [])
    assert [f.index for f in frames] == list(range(164))
    assert np.all(np.diff([f.time for f in frames]) > 0)
    with av.open(str(path)) as container:  # each frame is the picture the decoder gave in that place
        decoded = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    for i in (3, 4, 100):
        want = cv2.resize(decoded[i], frames[i].image.shape[1::-1], interpolation=cv2.INTER_AREA)
        assert np.abs(want.astype(int) - frames[i].image.astype(int)).mean() < 2.0


def test_skipping_deblocking_on_unreferenced_frames_cannot_drift(make_video):
    """"noref" leaves every frame another frame predicts from (all I and P frames) exactly as
    the full decode has it; "all" lets the error of the skipped deblocking spread into them."""
    rng = np.random.default_rng(3)
    texture = cv2.resize(rng.integers(0, 256, (30, 40, 3)).astype(np.uint8), (320, 240), interpolation=cv2.INTER_CUBIC)
    path = make_video((np.roll(texture, 2 * i, axis=1) for i in range(60)), crf=34)
    with av.open(str(path)) as container:
        kinds = [PictureType(frame.pict_type).name for frame in container.decode(video=0)]
    assert "B" in kinds and "P" in kinds
    decoded = {mode: [f.image for f in analysis_frames(
        path, AnalysisConfig(long_side=320, skip_loop_filter=mode, skip_unreferenced=False))]
        for mode in ("none", "noref", "all")}
    anchors = [i for i, kind in enumerate(kinds) if kind in "IP"]
    assert all(np.array_equal(decoded["noref"][i], decoded["none"][i]) for i in anchors)
    assert any(not np.array_equal(decoded["noref"][i], decoded["none"][i]) for i in range(len(kinds)))
    assert any(not np.array_equal(decoded["all"][i], decoded["none"][i]) for i in anchors if kinds[i] == "P")


def picture_types(path: Path) -> list[str]:
    with av.open(str(path)) as container:
        return [PictureType(frame.pict_type).name for frame in container.decode(video=0)]


def test_unreferenced_frames_are_left_undecoded_and_the_rest_keep_their_numbers(make_video):
    path = make_video((coded(i) for i in range(60)), fps=25)
    every = {f.index: f for f in analysis_frames(path, AnalysisConfig(long_side=64, skip_unreferenced=False))}
    report = DecodeReport()
    frames = list(analysis_frames(path, AnalysisConfig(long_side=64), report))
    kinds = picture_types(path)
    indices = [f.index for f in frames]
    # Every I and P frame is decoded (something predicts from them), so are B-frames used as
    # references (x264's pyramid); plain B-frames are not, and gaps stay short.
    assert {i for i, kind in enumerate(kinds) if kind in "IP"} <= set(indices)
    assert 0 < len(frames) < 45 and max(np.diff(indices)) <= 2
    assert (report.frames, report.unreferenced, report.missing, report.corrupt) == (len(frames), 60 - len(frames), 0, 0)
    for f in frames:  # the same pictures, numbers and times as a pass decoding everything
        assert read_index(f.image) == f.index and f.time == pytest.approx(every[f.index].time)
        np.testing.assert_array_equal(f.image, every[f.index].image)


def test_frames_at_gives_exactly_the_full_decode_across_key_frames(make_video):
    path = make_video((coded(i) for i in range(90)), fps=25, gop=20)
    config = AnalysisConfig(long_side=64)
    every = {f.index: f.image for f in analysis_frames(path, config.model_copy(update={"skip_unreferenced": False}))}
    decoded = {f.index for f in analysis_frames(path, config)}
    skipped = sorted(set(range(90)) - decoded)
    wanted = [skipped[0], skipped[1], 45, skipped[-1], 89, 3, 1000, -1]
    got = frames_at(path, wanted, config)
    assert sorted(got) == sorted(i for i in wanted if 0 <= i < 90)
    for i, image in got.items():
        np.testing.assert_array_equal(image, every[i])


@pytest.mark.parametrize("container_format, suffix", [("mpegts", "ts"), ("matroska", "mkv")])
def test_unreferenced_frames_are_found_in_annex_b_and_length_prefixed_streams(tmp_path, container_format, suffix):
    # MPEG-TS carries H.264 with start codes (Annex B), Matroska with length prefixes (avcC).
    path = tmp_path / f"video.{suffix}"
    with av.open(str(path), "w", format=container_format) as container:
        stream = container.add_stream("libx264", rate=25)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuv420p"
        stream.options = {"preset": "veryfast", "crf": "12"}
        for i in range(60):
            for packet in stream.encode(av.VideoFrame.from_ndarray(coded(i), format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    every = {f.index: f.image for f in analysis_frames(path, AnalysisConfig(long_side=64, skip_unreferenced=False))}
    report = DecodeReport()
    frames = list(analysis_frames(path, AnalysisConfig(long_side=64), report))
    assert len(every) == 60 and 0 < len(frames) < 45
    assert (report.unreferenced, report.missing) == (60 - len(frames), 0)
    assert all(read_index(f.image) == f.index and np.array_equal(f.image, every[f.index]) for f in frames)


def test_decoding_ahead_on_a_thread_gives_what_decoding_in_line_gives(make_video, tmp_path):
    """thread_type AHEAD (the default): the same frames and report as one decoder thread in
    line, corrupt packets included; an error reaches the consumer; leaving early stops it."""
    path = make_video((coded(i) for i in range(60)), gop=20)
    with av.open(str(path)) as container:
        packets = [(p.pos, p.size) for p in container.demux(video=0) if p.size]
    data = bytearray(path.read_bytes())
    for pos, size in packets[25:28]:
        data[pos + 4: pos + size] = np.random.default_rng(0).integers(0, 256, size - 4, dtype=np.uint8).tobytes()
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(bytes(data))
    assert AnalysisConfig().thread_type == "AHEAD"
    for source in (path, broken):
        made = {}
        for kind in ("AHEAD", "NONE"):
            report = DecodeReport()
            frames = list(analysis_frames(source, AnalysisConfig(long_side=64, thread_type=kind), report))
            made[kind] = ([(f.index, f.time, f.image.tobytes()) for f in frames], report)
        assert made["AHEAD"] == made["NONE"] and made["AHEAD"][0]
    assert made["AHEAD"][1].problems  # the broken one's report, complete once the frames are
    with pytest.raises(DecodeError, match="not a readable video"):
        list(analysis_frames(make_bad("text", tmp_path)))
    before = {t.name for t in threading.enumerate()}
    frames = analysis_frames(path, AnalysisConfig(long_side=64))
    assert next(frames).index == 0
    frames.close()
    assert "analysis-decode" not in {t.name for t in threading.enumerate()} - before
