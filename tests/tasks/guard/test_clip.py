"""guard_clip re-encodes a real clip with the face hidden; with the guard off it copies the file."""

import av
import numpy as np
import pytest

from tasks.guard import faces
from tasks.guard.clip import guard_clip
from tasks.guard.config import GuardConfig
from tasks.video import write_mp4


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


def test_guard_clips_in_place_rewrites_only_clips_with_faces(face_clip, tmp_path):
    import hashlib
    import shutil

    from tasks.guard.clip import find_faces, guard_clips

    faces.cv2.setNumThreads(1)
    with_face = shutil.copy(face_clip, tmp_path / "with_face.mp4")
    rng = np.random.default_rng(0)
    plain = write_mp4(tmp_path / "plain.mp4", rng.integers(0, 255, (6, 64, 64, 3), dtype=np.uint8), fps=10)
    before = hashlib.sha256(plain.read_bytes()).hexdigest()
    config = GuardConfig(detect_every=5)
    found, none = guard_clips([with_face, plain], config)
    assert len({d.frame for d in found}) >= 6 and none == ()
    assert hashlib.sha256(plain.read_bytes()).hexdigest() == before  # no face: not re-encoded
    assert find_faces(with_face, GuardConfig()) == ()  # the face is gone, searched on every frame
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plain.mp4", "with_face.mp4"]  # no temporary left
