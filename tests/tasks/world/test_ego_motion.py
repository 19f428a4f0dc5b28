"""A rig's metric ego-motion from its views (issue 33 point 4): checked on the simulator's own
renders of the surround rig, where the truth is the motion the simulator drove."""

import math

import numpy as np
import pytest

from tasks.manifests import load
from tasks.world import ego_motion, rig_views
from tasks.world.geometry import PinholeCamera

from tests.support import MANIFESTS


def test_a_planar_motion_moves_cameras_as_it_moves_points_and_is_recovered_from_two_poses():
    cam = PinholeCamera.from_fovy(64, 64, 90.0, [1.0, 0.5, 0.6], np.eye(3))
    motion = ego_motion.PlanarMotion(0.3, -0.2, math.radians(10))
    moved = motion.move(cam)
    assert np.allclose(moved.position, motion.apply(cam.position))
    back = ego_motion.true_motion(cam, moved)
    assert (back.dx, back.dy, back.yaw) == pytest.approx((0.3, -0.2, math.radians(10)))
    # A point the camera sees projects where the moved camera sees the moved point.
    point = np.array([[1.2, 0.6, -1.5]])
    assert np.allclose(cam.project(point), moved.project(motion.apply(point)))
    assert all(math.isnan(v) for v in ego_motion.error_cm(None, back, cam.position))  # nothing estimated
    assert ego_motion.error_cm(back, back, cam.position) == (0.0, 0.0)


def test_the_commanded_motion_integrates_the_held_velocities_over_the_interval_only():
    step_time = np.array([0.0, 0.1, 0.2, 0.3])
    action = np.array([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0], [5.0, 5.0]])
    centre = np.array([2.0, 1.0, 0.6])
    # 0.05-0.25 s: half of step 0, all of step 1, half of step 2.
    moved = ego_motion.commanded_motion(step_time, action, 0.05, 0.25, centre)
    assert moved.apply(centre)[:2] == pytest.approx(centre[:2] + [0.05 + 0.05, 0.2 + 0.05])
    assert moved.yaw == 0.0
    # A yaw rate turns the rig about its centre: the centre moves only as its velocity says.
    turning = ego_motion.commanded_motion(step_time, np.column_stack([action, np.full(4, 1.0)]), 0.0, 0.2, centre)
    assert turning.yaw == pytest.approx(0.2)
    assert turning.apply(centre)[:2] == pytest.approx(centre[:2] + [0.1, 0.2])
    assert ego_motion.commanded_motion(step_time, action, 1.0, 1.0, centre).apply(centre) == pytest.approx(centre)


@pytest.fixture(scope="module")
def rig():
    manifest = load(MANIFESTS / "vehicle_multiview.yaml")
    return rig_views.render_heldout(manifest, 10_000, "surround")


def test_the_renders_give_the_driven_motion_and_a_held_frame_gives_none(rig):
    names = [n for row in rig.layout for n in row]
    views = {n: rig.truth.frames[:, r * 64:(r + 1) * 64, c * 64:(c + 1) * 64]
             for r, row in enumerate(rig.layout) for c, n in enumerate(row)}
    errors, still, driven = [], [], []
    for k in range(4, 60, 8):
        truth = ego_motion.true_motion(rig.poses["front"][k], rig.poses["front"][k + 4])
        centre = np.mean([rig.poses[n][k].position for n in names], axis=0)
        args = ({n: rig.poses[n][k] for n in names}, {n: rig.depths[n][k] for n in names})
        estimate = ego_motion.estimate({n: views[n][k] for n in names}, {n: views[n][k + 4] for n in names}, *args)
        errors.append(ego_motion.error_cm(estimate, truth, centre)[0])
        held = ego_motion.estimate({n: views[n][k] for n in names}, {n: views[n][k] for n in names}, *args)
        still.append(100 * math.hypot(held.dx, held.dy))
        driven.append(100 * math.hypot(truth.dx, truth.dy))
    # The rig drove up to about 35 cm in each 0.4 s (slowing at the goal); the views put it
    # within a few cm of there.
    assert np.mean(driven) > 15
    assert np.median(errors) < 6 and np.mean(errors) < 0.3 * np.mean(driven), (errors, driven)
    assert max(still) < 1.0  # a frame held still says the rig stood still


def test_window_rows_score_every_source_and_copy_last_misses_by_the_whole_motion(rig):
    from tasks.world.physics import Window

    frames = rig.truth.frames
    windows = [Window(key=f"seed10000@{last}", true=frames[last + 1:last + 9],
                      outputs={"ceiling": frames[last + 1:last + 9], "model": frames[last + 1:last + 9],
                               "shuffled": frames[last + 1:last + 9][::-1].copy()},
                      context_last=frames[last], info={"episode": "seed10000", "last_context_frame": last})
               for last in (8, 24)]
    rows = rig_views.window_rows(windows, {"seed10000": rig}, [4, 8])
    assert len(rows) == 2 * 2 * len(rig_views.SOURCES)
    ego = {(r["horizon"], r["source"]): r for r in rig_views.ego_table(rows)}
    for h in (4, 8):
        floor = ego[(h, "floor")]
        assert floor["ego_mean_cm"] == pytest.approx(floor["true_mean_cm"], abs=0.5)
        assert ego[(h, "model")]["ego_mean_cm"] < 0.5 * floor["ego_mean_cm"]
        # The simulator drives as commanded to within its velocity servo's lag, so against the
        # command copy-last still misses by about the whole motion and the renders do not.
        assert ego[(h, "simulator")]["driven_vs_command_cm"] < 0.2 * floor["true_mean_cm"]
        assert floor["command_mean_cm"] > 0.7 * floor["true_mean_cm"]
        assert ego[(h, "model")]["command_mean_cm"] < 0.5 * floor["command_mean_cm"]
    views = rig_views.views_table(rows)
    assert {r["pair"] for r in views} == {"front-right", "front-left", "right-rear", "left-rear"}
    check = rig_views.check_beats_copy_last(rig_views.ego_table(rows), rows)
    assert check["passed"] and check["model_minus_floor_cm"]["4"]["mean"] < 0


def test_a_rig_that_does_not_tile_to_a_square_is_refused_before_anything_is_rendered():
    from schemas.manifest import Rig

    manifest = load(MANIFESTS / "vehicle_multiview.yaml")
    strip = manifest.model_copy(update={"rigs": (Rig(name="strip", layout=(("front", "right", "rear", "left"),)),)})
    with pytest.raises(ValueError, match="rig 'strip' tiles to 256x64; a world model sees square pictures"):
        rig_views.render_heldout(strip, 10_000, "strip")
    with pytest.raises(ValueError, match="no rig 'roof'"):
        rig_views.render_heldout(manifest, 10_000, "roof")
