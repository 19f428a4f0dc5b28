"""A control that does not fit its episode's video is refused in one line (tasks/controls/check.py)."""

import json

import numpy as np
import pytest

from schemas import paths
from tasks.controls.check import ControlError, check_controls
from tasks.controls.files import read_depth, read_segmentation, write_rendered
from tasks.controls.render import Rendered
from tasks.controls.video import write_video_controls

from tests.support import write_video

W, H, N = 32, 24, 6
LEGEND = ("background", "package", "table")


def rendered(frames=N, height=H, width=W, camera="side") -> Rendered:
    depth = np.full((frames, height, width), 650, np.uint16)
    ids = np.zeros((frames, height, width), np.uint8)
    ids[:, 4:8, 4:8] = 1
    return Rendered(depth_mm={camera: depth}, ids={camera: ids}, legend=LEGEND)


@pytest.fixture
def episode(tmp_path):
    """An episode folder as tasks.sim.files writes it: meta.json, the camera's video, its controls."""
    folder = tmp_path / "episode_000000"
    folder.mkdir()
    (folder / "meta.json").write_text(json.dumps({"cameras": ["side"], "index": 0}))
    frames = np.zeros((N, H, W, 3), np.uint8)
    frames[:, 8:16, 8:16] = 200
    write_video(folder / "side.mp4", frames, fps=10)
    write_rendered(rendered(), folder, {"side": 10.0})
    return folder


def test_matching_controls_pass_and_read_back(episode):
    found = check_controls(episode, "side")
    assert sorted(found) == ["depth", "seg"]
    assert found["depth"] == episode / "controls" / "side.depth.npz"
    assert np.allclose(read_depth(found["depth"]), 0.65)
    ids, legend = read_segmentation(found["seg"])
    assert legend == LEGEND and ids.shape == (N, H, W)
    write_video_controls(episode / "side.mp4", episode / paths.CONTROLS_DIR, "side")
    assert sorted(check_controls(episode, "side")) == ["blur", "depth", "edges", "seg"]


@pytest.mark.parametrize("wrong, said", [
    (dict(frames=N - 1), f"5 frames, the episode's side video has {N}"),
    (dict(height=H // 2), f"{W}x{H // 2} px, the episode's side video is {W}x{H}"),
    (dict(camera="front"), "rendered for camera 'front', not 'side'"),
])
def test_a_wrong_rendered_control_is_refused_in_one_line(episode, tmp_path, wrong, said):
    other = tmp_path / "other"
    written = write_rendered(rendered(**wrong), other, {wrong.get("camera", "side"): 10.0})
    camera = wrong.get("camera", "side")
    written[camera]["depth"].replace(paths.episode_control(episode, "side", "depth"))
    with pytest.raises(ControlError) as refused:
        check_controls(episode, "side")
    message = str(refused.value)
    assert message == f"{paths.episode_control(episode, 'side', 'depth')}: {said}" and "\n" not in message


def test_a_wrong_edges_video_is_refused(episode, tmp_path):
    short = write_video(tmp_path / "short.mp4", np.zeros((N - 2, H, W, 3), np.uint8), fps=10)
    write_video_controls(short, episode / paths.CONTROLS_DIR, "side")
    with pytest.raises(ControlError, match=f"side.edges.mp4: {N - 2} frames, the episode's side video has {N}"):
        check_controls(episode, "side")


def test_an_unknown_camera_a_broken_file_and_no_controls_are_refused(episode):
    with pytest.raises(ControlError, match="camera 'wrist' is not one of the episode's \\(side\\)"):
        check_controls(episode, "wrist")
    paths.episode_control(episode, "side", "seg").write_bytes(b"not an npz")
    with pytest.raises(ControlError, match="side.seg.npz: not a readable seg control"):
        check_controls(episode, "side")
    for control in ("depth", "seg"):
        paths.episode_control(episode, "side", control).unlink()
    with pytest.raises(ControlError, match="no controls of camera 'side'"):
        check_controls(episode, "side")
