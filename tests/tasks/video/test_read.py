"""Reading video: probe and the H.264 reference test, on tiny generated videos."""

from __future__ import annotations

import pytest

import numpy as np

from tasks.video import frame_rate, is_reference, probe, read_frames, write_mp4
from tests.support import coded, scene_frames


def test_probe_reports_what_the_file_declares(make_video):
    path = make_video((coded(i) for i in range(40)), fps=25)
    info = probe(path)
    assert (info.width, info.height, info.display_width, info.display_height) == (64, 48, 64, 48)
    assert info.n_frames == 40 and info.fps == pytest.approx(25.0) and info.duration == pytest.approx(1.6)
    assert info.codec == "h264" and info.rotation == 0 and info.sar == 1.0 and not info.vfr


def test_is_reference_reads_nal_ref_idc_in_both_framings():
    slice_ref, slice_unref, idr, sei = b"\x21\xe0", b"\x01\xe0", b"\x65\x88", b"\x06\x05"
    annex_b = b"\x00\x00\x00\x01\x09\xf0\x00\x00\x01"
    assert not is_reference(annex_b + slice_unref, 0)
    assert is_reference(annex_b + slice_ref, 0)
    assert is_reference(b"\x00\x00\x01" + idr, 0)

    def avcc(*units: bytes) -> bytes:
        return b"".join(len(u).to_bytes(4, "big") + u for u in units)

    assert not is_reference(avcc(sei, slice_unref, slice_unref), 4)
    assert is_reference(avcc(slice_unref, slice_ref), 4)  # one referenced slice is enough
    assert is_reference(avcc(sei), 4)  # no slice: nothing known, decode it
    assert is_reference(b"\x00\x00\x00\x09\x01", 4)  # a length past the end: unparsable


def test_read_frames_from_a_path_or_bytes_alike(tmp_path):
    path = write_mp4(tmp_path / "v.mp4", scene_frames(0, 64, 48, 10), 12)
    from_path, from_bytes = read_frames(path), read_frames(path.read_bytes())
    assert from_path.shape == (10, 48, 64, 3) and from_path.dtype == np.uint8
    assert np.array_equal(from_path, from_bytes)
    assert read_frames(path, max_frames=4).shape[0] == 4 and np.array_equal(read_frames(path, 4), from_path[:4])
    assert frame_rate(path) == 12.0

