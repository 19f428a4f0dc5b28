"""Contact sheet and panel video: layout, sizes, side-by-side world-model frames, face guard."""

import numpy as np
import pytest
from PIL import Image

from tasks.guard.config import GuardConfig
from tasks.guard.faces import detect_faces
from tasks.panels.sheet import (GAP, LABEL_H, SheetRow, contact_sheet, panel_frames, sample_indices,
                                video_layout, write_panel_media)
from tasks.video import read_frames


def _frames(n: int, h: int, w: int, value: int) -> np.ndarray:
    """n frames whose top-left pixel encodes the frame index, the rest a flat grey."""
    frames = np.full((n, h, w, 3), value, np.uint8)
    frames[:, 0, 0, 0] = np.arange(n)
    return frames


def test_sample_indices_span_first_to_last():
    assert sample_indices(30, 6).tolist() == [0, 6, 12, 17, 23, 29]
    assert sample_indices(3, 6).tolist() == [0, 1, 2]
    with pytest.raises(ValueError):
        sample_indices(0, 4)


def test_sheet_size_and_the_sampled_frames():
    rows = [SheetRow(f"cell{k}", _frames(30, 32, 48, 50 + k)) for k in range(3)]
    sheet = contact_sheet(rows, columns=6, label_width=100)
    assert sheet.shape == (2 * LABEL_H + 3 * (32 + GAP), 100 + 6 * (48 + GAP), 3)
    # Row 1, column 3 holds frame 17 of that row (its top-left pixel says so).
    y, x = 2 * LABEL_H + 1 * (32 + GAP), 100 + 3 * (48 + GAP)
    assert sheet[y, x, 0] == 17 and sheet[y + 5, x + 5, 0] == 51


def test_world_model_frames_sit_beside_the_simulators():
    sim, world = _frames(10, 16, 16, 40), _frames(10, 16, 16, 200)
    sheet = contact_sheet([SheetRow("a", sim, world), SheetRow("b", sim)], columns=2, label_width=60)
    assert sheet.shape == (2 * LABEL_H + 2 * (16 + GAP), 60 + 2 * (2 * 16 + GAP + GAP), 3)
    y = 2 * LABEL_H
    assert sheet[y + 4, 60 + 4, 1] == 40 and sheet[y + 4, 60 + 16 + GAP + 4, 1] == 200
    assert sheet[y + 16 + GAP + 4, 60 + 16 + GAP + 4, 1] != 200  # row b has no world frames: left blank


def test_rows_must_agree_on_frame_size():
    with pytest.raises(ValueError, match="share the frame size"):
        contact_sheet([SheetRow("a", _frames(4, 16, 16, 0)), SheetRow("b", _frames(4, 32, 16, 0))])
    with pytest.raises(ValueError, match="differ in size"):
        SheetRow("a", _frames(4, 16, 16, 0), _frames(4, 8, 8, 0))


def test_panel_video_grid_is_even_and_as_long_as_the_shortest_row():
    assert video_layout(7) == (3, 3) and video_layout(4) == (2, 2) and video_layout(1) == (1, 1)
    rows = [SheetRow(f"c{k}", _frames(12 - k, 15, 21, 90)) for k in range(5)]
    frames = list(panel_frames(rows))
    assert len(frames) == 8
    h, w = frames[0].shape[:2]
    assert h % 2 == 0 and w % 2 == 0 and (h, w) == (2 * (15 + LABEL_H + GAP), 3 * (21 + GAP) + 1)


@pytest.fixture(scope="module")
def astronaut() -> np.ndarray:
    """A 256 x 256 crop of scikit-image's bundled astronaut photo: a face about 92 px wide."""
    skimage_data = pytest.importorskip("skimage.data", reason="scikit-image (dev extra) not installed")
    return np.ascontiguousarray(skimage_data.astronaut()[:256, 96:352])


def test_media_pass_the_face_guard(tmp_path, astronaut):
    frames = np.stack([astronaut] * 4)
    rows = [SheetRow("faces", frames)]
    media = write_panel_media(rows, tmp_path / "sheet.png", tmp_path / "panel.mp4", fps=10,
                              guard=GuardConfig(detect_every=2), columns=2)
    assert media.frames == 4 and len(media.sheet_faces) == 2 and media.video_faces  # one face per sheet tile
    assert {d.frame for d in media.video_faces} == {0, 1, 2, 3}
    plain = write_panel_media(rows, tmp_path / "raw.png", tmp_path / "raw.mp4", fps=10, guard=None, columns=2)
    faces = detect_faces(np.asarray(Image.open(plain.sheet)))
    assert not plain.sheet_faces and len(faces) == 2

    def over_a_face(found):  # a detection on what was a face (the blur's edges may fool Haar elsewhere)
        return [b for b in found if any(x <= b[0] + b[2] / 2 <= x + w and y <= b[1] + b[3] / 2 <= y + h
                                        for x, y, w, h in faces)]
    assert over_a_face(detect_faces(np.asarray(Image.open(media.sheet)))) == []
    assert all(detect_faces(f) == [] for f in read_frames(media.video))
