"""The detector's package track read out frame by frame (`track_package`), against the
simulator's own package pose."""

import numpy as np
import pytest

from tasks.manifests import load
from tasks.panels.detect import PACKAGE_HALF, TABLE_TOP, project, seen_height, track_package
from tasks.sim.episode import rollout

from tests.support import MANIFESTS

pytestmark = pytest.mark.slow  # simulates and renders a MuJoCo episode


def test_the_track_follows_the_simulated_package_every_frame():
    manifest = load(MANIFESTS / "push_closeup.yaml").model_copy(update={"horizon_s": 4.0})
    ep = rollout(manifest, 21)
    camera = manifest.cameras[0]
    frames = ep.frames[camera.name]
    track = track_package(frames, camera, ep.object_pose[0, 0, :3])
    assert track.shape == (len(frames), 2) and not np.isnan(track).any()
    poses = ep.object_pose[::len(ep.object_pose) // len(frames), 0, :3][:len(frames)]
    truth = np.array([project(camera, np.array([[x, y, seen_height(camera, np.array([x, y, TABLE_TOP + PACKAGE_HALF[2]]))]]))[0]
                      for x, y, _ in poses])
    assert np.linalg.norm(truth[-1] - truth[0]) > 20  # pushed across the picture
    assert np.linalg.norm(track - truth, axis=1).max() < 2.5
    # A package painted over from frame 30 on is not seen there.
    hidden = frames.copy()
    hidden[30:] = hidden[30:].mean(axis=(1, 2), keepdims=True).astype(np.uint8)
    lost = track_package(hidden, camera, ep.object_pose[0, 0, :3])
    assert not np.isnan(lost[:30]).any() and np.isnan(lost[30:]).all()
