"""Edge and blur controls of any video (tasks/controls/video.py), on frames whose edges are known."""

import numpy as np
import pytest

from tasks.controls.check import ControlError
from tasks.controls.sources import find_sources
from tasks.controls.video import blur_sigma, canny_thresholds, read_edges, video_controls, write_video_controls

from tests.support import write_video

W, H, N, SIDE = 64, 48, 12, 16


def square_frames() -> np.ndarray:
    """A bright square on a dark ground moving 2 px right a frame: its outline is the only edge."""
    frames = np.full((N, H, W, 3), 40, np.uint8)
    for i in range(N):
        frames[i, 16:16 + SIDE, 8 + 2 * i: 8 + 2 * i + SIDE] = 200
    return frames


@pytest.fixture(scope="module")
def square_video(tmp_path_factory):
    return write_video(tmp_path_factory.mktemp("controls") / "square.mp4", square_frames(), fps=10)


def test_canny_edges_lie_on_the_squares_outline(square_video):
    made = video_controls(square_video)
    assert made["edges"].shape == (N, H, W) and set(np.unique(made["edges"])) == {0, 255}
    for i, edges in enumerate(made["edges"]):
        outline = np.zeros((H, W), bool)
        r0, c0 = 16, 8 + 2 * i
        outline[r0 - 1: r0 + SIDE + 1, c0 - 1: c0 + SIDE + 1] = True
        outline[r0 + 1: r0 + SIDE - 1, c0 + 1: c0 + SIDE - 1] = False  # a band a pixel either side of the border
        found = edges > 0
        assert not (found & ~outline).any(), f"frame {i}: an edge off the outline"
        assert (found & outline).sum() >= 4 * (SIDE - 2), f"frame {i}: outline not found"


def test_blur_keeps_the_picture_and_softens_it(square_video):
    made = video_controls(square_video)
    blur, frames = made["blur"].astype(float), square_frames().astype(float)
    assert made["blur"].shape == (N, H, W, 3) and made["blur"].dtype == np.uint8
    assert abs(blur.mean() - frames.mean()) < 2.0
    steepest = lambda x: np.abs(np.diff(x, axis=2)).max()  # noqa: E731
    assert steepest(blur) < 0.5 * steepest(frames)
    assert blur_sigma(48, 64) == 1.5 and blur_sigma(360, 640) == 11.25


def test_thresholds_follow_the_median_with_a_floor():
    assert canny_thresholds(np.full(10, 100, np.uint8)) == pytest.approx((66.0, 133.0))
    assert canny_thresholds(np.zeros(10, np.uint8)) == (10.0, 20.0)  # a black video: no noise edges


def test_written_edges_read_back_exactly(square_video, tmp_path):
    written = write_video_controls(square_video, tmp_path, "square")
    assert sorted(p.name for p in written.values()) == ["square.blur.mp4", "square.edges.mp4"]
    assert np.array_equal(read_edges(written["edges"]), video_controls(square_video)["edges"])


def test_what_is_not_a_video_is_refused_in_one_line(tmp_path, square_video):
    notes = tmp_path / "notes.mp4"
    notes.write_text("not a video\n")
    empty = tmp_path / "empty"
    empty.mkdir()
    for path, said in ((notes, "not a readable video"), (tmp_path / "missing.mp4", "no such file or folder"),
                       (empty, "no videos there")):
        with pytest.raises(ControlError, match=said) as refused:
            find_sources(path)
        assert str(refused.value).startswith(str(path)) and "\n" not in str(refused.value)
    (found,) = find_sources(square_video, tmp_path / "out")
    assert found.folder == tmp_path / "out" and found.name == "square" and found.camera is None
