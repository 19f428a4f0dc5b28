"""Depth and segmentation rendered beside the RGB frames (tasks/controls/render.py): the
geometry they must agree with comes from the camera's pinhole model (tasks/panels/detect.py)."""

import cv2
import numpy as np
import pytest
import yaml

from schemas.manifest import ScenarioManifest
from tasks.controls.render import Recorder
from tasks.panels.detect import PACKAGE_HALF, TABLE_TOP, depth, on_plane, project
from tasks.sim.episode import rollout

from tests.support import MANIFESTS

pytestmark = pytest.mark.slow  # simulates and renders MuJoCo episodes


def closeup(**changes) -> ScenarioManifest:
    """push_closeup (the side camera at 64 px, 10 fps) for 1 s: 10 frames."""
    body = yaml.safe_load((MANIFESTS / "push_closeup.yaml").read_text())
    body["horizon_s"] = 1.0
    body["stressors"] += changes.get("stressors", [])
    return ScenarioManifest.model_validate(body)


@pytest.fixture(scope="module")
def still():
    manifest = closeup()
    recorder = Recorder()
    return manifest, rollout(manifest, 21, on_frame=recorder), recorder.rendered()


def test_controls_leave_the_rgb_frames_as_they_were(still):
    manifest, with_controls, rendered = still
    plain = rollout(manifest, 21)
    assert all(np.array_equal(plain.frames[c], with_controls.frames[c]) for c in plain.frames)
    assert rendered.depth_mm["side"].shape == (10, 64, 64) and rendered.depth_mm["side"].dtype == np.uint16
    assert rendered.ids["side"].shape == (10, 64, 64) and rendered.ids["side"].dtype == np.uint8


def test_depth_on_the_table_is_the_camera_geometry_within_2_mm(still):
    manifest, _, rendered = still
    camera = manifest.cameras[0]
    ids, depth_mm = rendered.ids["side"][0], rendered.depth_mm["side"][0]
    rows, cols = np.nonzero(ids == rendered.legend.index("table"))
    points = np.array([on_plane(camera, np.array([c + 0.5, r + 0.5]), TABLE_TOP) for r, c in zip(rows, cols)])
    # The top (tasks/sim/scene.py: x 0.25 to 0.65, y within 0.35), not the front face below its edge.
    top = (points[:, 0] > 0.26) & (points[:, 0] < 0.64) & (np.abs(points[:, 1]) < 0.34)
    assert top.sum() > 500
    expected = np.array([depth(camera, p) for p in points[top]])
    error = np.abs(depth_mm[rows[top], cols[top]] / 1000.0 - expected)
    assert error.max() < 0.002, error.max()  # measured 0.0005 m (2026-11-26): the rounding to millimetres
    # The image centre, where the optical axis meets the table (0.652 m away).
    centre = depth(camera, on_plane(camera, np.array([32.0, 32.0]), TABLE_TOP))
    assert abs(depth_mm[31:33, 31:33].mean() / 1000.0 - centre) < 0.002


def test_the_package_pixels_are_where_the_package_projects(still):
    manifest, episode, rendered = still
    camera, package = manifest.cameras[0], rendered.legend.index("package")
    assert rendered.legend[0] == "background" and {"package", "goal", "table", "robot"} <= set(rendered.legend)
    pos = episode.object_pose[0, 0, :3]  # frame 0 is rendered from the state before step 0
    # The package may be turned about z: its bounding circle's corners bound it.
    reach = np.hypot(*PACKAGE_HALF[:2])
    corners = pos + np.array([[sx * reach, sy * reach, sz * PACKAGE_HALF[2]]
                              for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    (c0, r0), (c1, r1) = project(camera, corners).min(axis=0), project(camera, corners).max(axis=0)
    rows, cols = np.nonzero(rendered.ids["side"][0] == package)
    assert rows.size > 20
    assert rows.min() >= np.floor(r0) - 1 and rows.max() <= np.ceil(r1) and cols.min() >= np.floor(c0) - 1
    assert cols.max() <= np.ceil(c1)
    col, row = project(camera, pos[None])[0]
    assert rendered.ids["side"][0][int(row), int(col)] == package


def _boundary(ids: np.ndarray) -> np.ndarray:
    edge = np.zeros(ids.shape, bool)
    edge[:, 1:] |= ids[:, 1:] != ids[:, :-1]
    edge[1:, :] |= ids[1:, :] != ids[:-1, :]
    return edge


def _on_rgb_edges(ids: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """Per frame, the share of segment-boundary pixels within a pixel of a Canny edge of the RGB frame."""
    shares = []
    for seg, frame in zip(ids, frames):
        edges = cv2.Canny(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY), 30, 60)
        near = cv2.dilate(edges, np.ones((3, 3), np.uint8)) > 0
        boundary = _boundary(seg)
        shares.append((boundary & near).sum() / boundary.sum())
    return np.array(shares)


def test_controls_follow_the_camera_jitter():
    """With a 4 degree shake (about 7 px at 64 px) the segment boundaries stay on the RGB frame's
    edges in every frame; rendered from the unshaken camera they fall off them."""
    manifest = closeup(stressors=[{"kind": "camera_jitter", "amplitude_deg": 4.0, "frequency_hz": 3}])
    shaken, still = Recorder(), Recorder()

    def both(scene, renderer, data, camera, angles):
        shaken(scene, renderer, data, camera, angles)
        still(scene, renderer, data, camera, None)

    episode = rollout(manifest, 21, on_frame=both)
    followed = _on_rgb_edges(shaken.rendered().ids["side"], episode.frames["side"])
    unshaken = _on_rgb_edges(still.rendered().ids["side"], episode.frames["side"])
    assert followed.min() > 0.85, followed  # measured 0.93 to 0.98
    assert unshaken.mean() < followed.mean() - 0.2, unshaken  # measured mean 0.60
