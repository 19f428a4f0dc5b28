"""The frame detector: pinhole geometry, and push verdicts against the simulator's own."""

import numpy as np
import pytest

from tasks.manifests import load
from tasks.panels.detect import judge_frames, on_plane, project
from tasks.sim.episode import rollout
from tasks.sim.scene import build_scene

from tests.support import MANIFESTS

PUSH = load(MANIFESTS / "conveyor_push.yaml")
NOISY = PUSH.model_copy(update={"task": PUSH.task.model_copy(update={"controller_noise": 0.8})})


def test_projection_round_trips_and_matches_the_render():
    cam = PUSH.cameras[0]
    points = np.array([[0.45, 0.0, 0.1], [0.3, -0.2, 0.16], [0.6, 0.25, 0.0]])
    pixels = project(cam, points)
    assert np.allclose(pixels[0], [64, 64], atol=1e-6)  # on the optical axis of the overhead camera
    for p, px in zip(points, pixels):
        assert np.allclose(on_plane(cam, px, p[2]), p, atol=1e-9)
    # The goal disc (saturated green) is where its centre projects in the first rendered frame.
    scene = build_scene(PUSH, 11)
    frame = rollout(PUSH.model_copy(update={"horizon_s": 0.1}), 11).frames["overhead"][0]
    col, row = project(cam, np.array([[*scene.goal[:2], 0.1]]))[0].round().astype(int)
    r, g, b = frame[row, col].astype(int)
    assert g > 200 and g > 1.6 * r and g > 1.3 * b


@pytest.mark.parametrize("seed", [11, 13], ids=["miss", "hit"])
def test_push_verdict_from_frames_matches_the_simulator(seed):
    ep = rollout(NOISY, seed)
    truth = float(np.linalg.norm(ep.object_pose[-1, 0, :2] - build_scene(NOISY, seed).goal[:2]))
    verdict = judge_frames(ep.frames["overhead"], NOISY.cameras[0], NOISY.evaluation, ep.object_pose[0, 0, :3])
    assert verdict.success == ep.success, (verdict.reason, ep.reason)
    assert abs(verdict.distance_m - truth) < 0.015


def test_undecided_without_a_detector_or_a_visible_goal():
    aisle = load(MANIFESTS / "mobile_rig_aisle.yaml")  # reach_goal: no frame detector
    frames = np.zeros((5, 128, 128, 3), np.uint8)
    assert judge_frames(frames, aisle.cameras[0], aisle.evaluation, np.zeros(3)).success is None
    dark = judge_frames(frames, PUSH.cameras[0], PUSH.evaluation, np.array([0.45, -0.14, 0.13]))
    assert dark.success is None and "goal marker not found" in dark.reason


@pytest.mark.parametrize("cell,seed", [("dim", 13), ("jitter", 13), ("occluder", 13), ("jitter", 11)])
def test_push_verdict_under_the_default_grids_visual_stressors(cell, seed):
    from tasks.panels.grid import default_grid, expand

    spec, variants = expand(NOISY, default_grid(NOISY))
    variant = variants[[v.cell for v in spec.variants].index(cell)]
    ep = rollout(variant, seed)
    verdict = judge_frames(ep.frames["overhead"], variant.cameras[0], variant.evaluation, ep.object_pose[0, 0, :3])
    assert verdict.success == ep.success, (verdict.reason, ep.reason)


@pytest.mark.parametrize("seed", [26, 23], ids=["miss", "hit"])
def test_push_verdict_from_a_side_camera(seed):
    """push_closeup's camera looks at the table from the side (about 32 degrees down): the goal
    disc is an ellipse and the package shows its front face too; sizes and heights come from
    the camera's pose, so the verdicts still match the simulator's (24 of 24 on seeds 21-32 at
    controller noise 0.3 and 0.8, measured 2026-11-24)."""
    closeup = load(MANIFESTS / "push_closeup.yaml")
    noisy = closeup.model_copy(update={"task": closeup.task.model_copy(update={"controller_noise": 0.8})})
    ep = rollout(noisy, seed)
    verdict = judge_frames(ep.frames["side"], noisy.cameras[0], noisy.evaluation, ep.object_pose[0, 0, :3])
    assert verdict.success == ep.success, (verdict.reason, ep.reason)
    if ep.success:
        truth = float(np.linalg.norm(ep.object_pose[-1, 0, :2] - build_scene(noisy, seed).goal[:2]))
        assert abs(verdict.distance_m - truth) < 0.015


def test_a_package_lost_for_a_while_is_found_again():
    """A decoder's colours can drift for several frames (a world model's rollout, a tokenizer's
    reconstruction): the package is then invisible while it moves. Frames 10 to the last 8 of
    a successful push are blanked here; the track must pick the package up again at the goal
    rather than report it where it was last seen."""
    closeup = load(MANIFESTS / "push_closeup.yaml")
    noisy = closeup.model_copy(update={"task": closeup.task.model_copy(update={"controller_noise": 0.8})})
    ep = rollout(noisy, 23)
    assert ep.success
    frames = ep.frames["side"].copy()
    frames[10:-8] = np.median(frames[0].reshape(-1, 3), axis=0).astype(np.uint8)
    verdict = judge_frames(frames, noisy.cameras[0], noisy.evaluation, ep.object_pose[0, 0, :3])
    truth = float(np.linalg.norm(ep.object_pose[-1, 0, :2] - build_scene(noisy, 23).goal[:2]))
    assert verdict.success, verdict.reason
    assert abs(verdict.distance_m - truth) < 0.015


@pytest.mark.parametrize("seed", [26, 23], ids=["miss", "hit"])
def test_generated_frames_are_judged_by_the_goal_disc_of_the_real_first_frame(seed):
    """A world model's frames: the goal is looked for in the real first frame (the reference),
    and the verdict is whether the disc is covered at the end, whatever colour the package
    has become; a first frame that does not draw the disc is undecided."""
    closeup = load(MANIFESTS / "push_closeup.yaml")
    noisy = closeup.model_copy(update={"task": closeup.task.model_copy(update={"controller_noise": 0.8})})
    ep = rollout(noisy, seed)
    frames, start = ep.frames["side"], ep.object_pose[0, 0, :3]
    drifted = frames.copy()
    drifted[..., 0] = np.clip(drifted[..., 0].astype(int) + 40, 0, 255)  # every colour shifted towards red
    verdict = judge_frames(drifted, noisy.cameras[0], noisy.evaluation, start, reference=frames[0])
    assert verdict.success == ep.success, (verdict.reason, ep.reason)
    assert ("covered" if ep.success else "uncovered") in verdict.reason
    # A tokenizer that never saw dim light reconstructs a murk without the green disc.
    murk = np.repeat((frames.mean(axis=-1, keepdims=True) * 0.3).astype(np.uint8), 3, axis=-1)
    undrawn = judge_frames(murk, noisy.cameras[0], noisy.evaluation, start, reference=frames[0])
    assert undrawn.success is None and "not drawn" in undrawn.reason


def test_a_partly_covered_disc_with_a_track_near_the_tolerance_is_undecided():
    """push_closeup at controller noise 0.8, seed 73: the package stops 0.071 m from the goal
    (a failure) with 82% of the disc still visible, and its track ends 0.044 m from it, within
    the tracker's precision of the 0.05 m tolerance; before version 5 the track called it a
    success. Neither cue can tell, so the verdict is undecided."""
    from tasks.panels.detect import TRACK_PRECISION_M

    closeup = load(MANIFESTS / "push_closeup.yaml")
    noisy = closeup.model_copy(update={"task": closeup.task.model_copy(update={"controller_noise": 0.8})})
    ep = rollout(noisy, 73)
    assert not ep.success
    verdict = judge_frames(ep.frames["side"], noisy.cameras[0], noisy.evaluation, ep.object_pose[0, 0, :3])
    assert verdict.success is None and "tracker's precision" in verdict.reason, verdict.reason
    assert abs(verdict.distance_m - noisy.evaluation.goal_tolerance_m) <= TRACK_PRECISION_M


def test_a_package_recoloured_green_still_covers_the_disc():
    """The appearance stressor recolours everything: on push_closeup seed 10322 the package comes
    out green, and resting on the goal it kept the disc's pixels green, so version 5 read the
    disc as uncovered (100% visible) and the success as a failure. A rendered disc pixel counts
    as visible only if it also keeps its first-frame colour."""
    from schemas.manifest import Appearance
    from schemas.panel import StressorCell, StressorGrid
    from tasks.panels.grid import expand

    closeup = load(MANIFESTS / "push_closeup.yaml")
    cell = StressorCell(name="appearance", stressors=(Appearance(colour_jitter=0.9, texture=True),))
    _, (variant,) = expand(closeup, StressorGrid(name="g", description="d", cells=(cell,), episodes=1,
                                                 seed=closeup.seed + 10300))
    ep = rollout(variant, 10322)
    assert ep.success
    verdict = judge_frames(ep.frames["side"], variant.cameras[0], variant.evaluation, ep.object_pose[0, 0, :3])
    assert verdict.success, verdict.reason


def test_a_disc_covered_by_something_other_than_the_package_is_undecided():
    """A poor policy can park the arm over the goal while the package lies far off (a state
    policy trained 20 steps did, on push_closeup seed 10321: 47% of the disc visible, the
    package tracked 0.244 m away); version 7 called that a success. Here seed 24's miss (the
    package 0.252 m from the goal) gets the disc hidden in its last frames: the cover and the
    track contradict each other, so the verdict is undecided, not a success."""
    from scipy import ndimage

    from tasks.panels.detect import _goal_mask

    closeup = load(MANIFESTS / "push_closeup.yaml")
    noisy = closeup.model_copy(update={"task": closeup.task.model_copy(update={"controller_noise": 0.8})})
    ep = rollout(noisy, 24)
    assert not ep.success
    frames = ep.frames["side"].copy()
    disc = ndimage.binary_dilation(_goal_mask(frames[0], noisy.cameras[0], noisy.evaluation.goal_tolerance_m),
                                   iterations=2)
    plain = judge_frames(frames, noisy.cameras[0], noisy.evaluation, ep.object_pose[0, 0, :3])
    assert plain.success is False and "uncovered" in plain.reason
    frames[-10:, disc] = (38, 38, 40)  # the gripper fingers' dark grey
    verdict = judge_frames(frames, noisy.cameras[0], noisy.evaluation, ep.object_pose[0, 0, :3])
    assert verdict.success is None and "too far to be what covers it" in verdict.reason, verdict.reason
    assert verdict.distance_m > 0.2
