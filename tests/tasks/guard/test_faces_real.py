"""The face guard on hand-labelled real footage (tests/tasks/guard/face_boxes.json): the bikes.mp4
cyclist whose face the Haar cascades left sharp (issue 27) is hidden on every labelled frame, and a
clip on which no face is found is left as it is, with no decision to tag it guard:faces_hidden."""

import json
from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from tasks.curate.config import CurateConfig
from tasks.guard.clip import guard_clips
from tasks.guard.faces import guard_frames
from tasks.video import write_mp4

LABELS = json.loads((Path(__file__).parent / "face_boxes.json").read_text())


@pytest.fixture(scope="module", autouse=True)
def one_opencv_thread():
    before = cv2.getNumThreads()
    cv2.setNumThreads(1)
    yield
    cv2.setNumThreads(before)


@pytest.fixture(scope="module")
def bikes(shared_data) -> np.ndarray:
    with av.open(str(shared_data / "videos" / "bikes.mp4")) as container:
        return np.stack([f.to_ndarray(format="rgb24") for f in container.decode(video=0)])


def _detail(frame: np.ndarray, box) -> float:
    x, y, w, h = box
    grey = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY).astype(np.float32)
    return float(np.abs(cv2.Laplacian(grey, cv2.CV_32F))[y:y + h, x:x + w].mean())


def test_the_bikes_cyclist_face_is_hidden(bikes):
    # The shot 76-136, guarded as curation guards it (every 5th frame searched, boxes carried between).
    shot = bikes[76:137]
    out, decisions = guard_frames(shot, CurateConfig().guard)
    labelled = {int(k): v for k, v in LABELS["videos"]["bikes.mp4"]["frames"].items() if v}
    assert set(labelled) <= set(range(76, 137))
    for f, boxes in labelled.items():
        for box in boxes:  # the cyclist's face, about 25 x 30 px
            assert _detail(out[f - 76], box) < 0.5 * _detail(shot[f - 76], box), f"frame {f}: face left sharp"


def test_a_clip_with_no_face_found_is_not_re_encoded_nor_tagged(bikes, tmp_path):
    """bikes.mp4 90-102: a van and a tree before the cyclist rides into view, no face (labelled
    frame 100). The Haar cascades found a 'face' on frame 100, so the clip was blurred and tagged."""
    clip = write_mp4(tmp_path / "no_face.mp4", bikes[90:103], fps=25, crf=18)
    before = clip.read_bytes()
    found, = guard_clips([clip], CurateConfig().guard)
    assert found == ()  # flows.curate tags guard:faces_hidden only when this is not empty
    assert clip.read_bytes() == before
