"""guard_clip re-encodes a real clip with the face hidden; with the guard off it copies the file."""

import av
import numpy as np
import pytest

from tasks.guard import faces
from tasks.guard.clip import guard_clip
from tasks.guard.config import GuardConfig
from tasks.mp4 import write_mp4


@pytest.fixture(scope="module")
def face_clip(shared_data, tmp_path_factory):
    """12 frames of carphone_pristine.mp4 (every 10th), 176 x 144, as an H.264 MP4."""
    with av.open(str(shared_data / "videos" / "carphone_pristine.mp4")) as container:
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)][::10]
    return write_mp4(tmp_path_factory.mktemp("guard") / "face.mp4", frames, fps=10, crf=12)


def _decode(path):
    with av.open(str(path)) as container:
        return np.stack([f.to_ndarray(format="rgb24") for f in container.decode(video=0)])


def test_guard_clip_hides_the_face(face_clip, tmp_path):
    faces.cv2.setNumThreads(1)
    out = guard_clip(face_clip, tmp_path / "guarded.mp4")
    frames = _decode(out.path)
    assert frames.shape == (12, 144, 176, 3) and (out.frames, out.width, out.height) == (12, 176, 144)
    assert len({d.frame for d in out.decisions}) >= 6 and all(d.detected for d in out.decisions)
    assert [i for i, f in enumerate(frames) if faces.detect_faces(f)] == []
    assert out.bytes == out.path.stat().st_size and len(out.sha256) == 64
    # Far from every box the guarded clip differs from the source no more than a plain
    # re-encode with the same settings does (x264's loss), i.e. nothing else was touched.
    source = _decode(face_clip)
    plain = _decode(write_mp4(tmp_path / "plain.mp4", source, fps=10, crf=23))
    far = np.ones(source.shape[:3], bool)
    for d in out.decisions:
        x, y, w, h = d.box
        far[d.frame, max(0, y - 16):y + h + 16, max(0, x - 16):x + w + 16] = False
    loss = np.abs(plain.astype(int) - source.astype(int))[far].mean()
    assert np.abs(frames.astype(int) - source.astype(int))[far].mean() < 1.2 * loss + 0.2


def test_guard_off_copies_the_file(face_clip, tmp_path):
    out = guard_clip(face_clip, tmp_path / "copy.mp4", GuardConfig(enabled=False))
    assert out.path.read_bytes() == face_clip.read_bytes() and out.decisions == ()
