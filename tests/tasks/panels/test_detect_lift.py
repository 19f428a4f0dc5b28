"""The lift detector: its geometry, and bin-pick verdicts from frames against the simulator's own."""

import numpy as np
import pytest

from tasks.manifests import load
from tasks.panels import detect, detect_lift
from tasks.panels.detect import judge_frames, project
from tasks.policy.base import ScriptedPolicy
from tasks.sim import scene
from tasks.sim.episode import rollout

from tests.support import MANIFESTS

PICK = load(MANIFESTS / "bin_pick.yaml")
FRONT = PICK.cameras[0]


def test_constants_follow_the_scene():
    assert np.allclose(detect_lift.BIN_CENTRE, scene.BIN_CENTRE)
    assert detect_lift.BIN_INNER == scene.BIN_INNER
    assert np.allclose(detect.PACKAGE_HALF, scene.PACKAGE_HALF) and detect_lift.BIN_FLOOR == scene.BIN_FLOOR


def test_a_package_seen_above_its_start_resting_in_the_bin_or_knocked_out():
    start, need = np.array([0.46, 0.01, 0.041]), PICK.evaluation.lift_height_m

    def seen(point, size=None):
        return detect_lift.lift_seen(FRONT, project(FRONT, np.asarray(point)[None])[0], start, size)[0]

    assert seen(start + [0, 0, 0.3]) == pytest.approx(0.3, abs=1e-6)
    assert seen(start + [0, 0, 0.05]) is None  # its ray meets the bin floor: resting at the far side, or lifted?
    assert seen([0.52, 0.05, 0.041]) is None  # resting in the bin nearer the camera: no reading either
    behind = np.array([0.1, 0.0, start[2] - detect_lift.BIN_FLOOR])  # knocked out of the bin, resting behind it
    assert seen(behind) > need  # by its ray alone it could be lifted above the start
    assert seen(behind, size=detect_lift._area(FRONT, behind)) is None  # but it is a resting package's size there
    assert seen(behind, size=3 * detect_lift._area(FRONT, behind)) > need  # too large to rest there: lifted


@pytest.mark.parametrize("seed,noise", [(30000, 0.3), (30002, 1.0)], ids=["lifted", "never-lifted"])
def test_lift_verdict_from_frames_matches_the_simulator(seed, noise):
    ep = rollout(PICK, seed, controller=ScriptedPolicy(noise).controller, record=("front",))
    verdict = judge_frames(ep.frames["front"], FRONT, PICK.evaluation, ep.object_pose[0, 0, :3])
    assert ep.success == (noise < 0.5)  # the two outcomes this test is about
    assert verdict.success == bool(ep.success), verdict.reason


def test_a_package_that_leaves_and_is_not_found_is_undecided():
    ep = rollout(PICK, 30000, controller=ScriptedPolicy(0.3).controller, record=("front",))
    frames = ep.frames["front"].copy()
    start = ep.object_pose[0, 0, :3]
    px = project(FRONT, start[None])[0].round().astype(int)
    frames[1:, px[1] - 6: px[1] + 7, px[0] - 6: px[0] + 7] = (90, 160, 60)  # the start covered up
    frames[-20:] = frames[1]  # and nothing of its colours anywhere that changed at the end
    frames[-20:, :60] = (90, 160, 60)
    verdict = judge_frames(frames, FRONT, PICK.evaluation, start)
    assert verdict.success is None and "found in" in verdict.reason


def test_generated_frames_are_not_judged_by_the_lift_detector():
    frames = np.zeros((4, 128, 128, 3), np.uint8)
    verdict = judge_frames(frames, FRONT, PICK.evaluation, np.array([0.45, 0.0, 0.041]), reference=frames[0])
    assert verdict.success is None and "rendered frames only" in verdict.reason
