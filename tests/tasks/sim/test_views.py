"""The multi-view vehicle rig and the camera-control rig (issue 33): body-mounted cameras ride on
the base along its commanded waypoints, every view is recorded and written, and the recorded
action is the cameras' own motion."""

import numpy as np

from tasks.manifests import load
from tasks.sim.episode import Simulation, rollout, write_episode
from tasks.sim.scene import AISLE_GOAL_X, build_scene, drive_path

from tests.support import MANIFESTS

VEHICLE = load(MANIFESTS / "vehicle_multiview.yaml")
CONTROL = load(MANIFESTS / "camera_control_aisle.yaml")


def _rollout_with_camera_poses(manifest):
    """The episode and, per camera, its world position at each of its frames."""
    seen: dict[str, list[np.ndarray]] = {c.name: [] for c in manifest.cameras}

    def on_frame(scene, renderer, data, camera, angles):
        seen[camera].append(data.cam_xpos[scene.model.camera(camera).id].copy())

    ep = rollout(manifest, manifest.seed, on_frame=on_frame)
    return ep, {name: np.array(p) for name, p in seen.items()}


def test_the_vehicle_drives_its_path_and_all_four_views_move_with_it(tmp_path):
    ep, cams = _rollout_with_camera_poses(VEHICLE)
    assert ep.success, ep.reason
    names = [c.name for c in VEHICLE.cameras]
    assert set(names) >= {"front", "rear", "left", "right"} and sorted(ep.frames) == sorted(names)
    for cam in VEHICLE.cameras:
        frames = ep.frames[cam.name]
        assert frames.shape == (round(VEHICLE.horizon_s * cam.fps), cam.resolution[1], cam.resolution[0], 3)
        assert frames.std() > 5 and not np.array_equal(frames[0], frames[-1])  # a real, moving view
        # Mounted on the base: the camera's world position is the base's plus its fixed offset.
        path = cams[cam.name]
        assert np.linalg.norm(path[-1] - path[0]) > 2.5
        base_at_frame = ep.joint_pos[np.searchsorted(ep.time, ep.frame_time[cam.name]), :2]
        offset = path[:, :2] - base_at_frame
        assert np.allclose(offset, offset[0], atol=0.05) and np.allclose(offset[0], cam.position[:2], atol=0.05)
    # The front camera looks ahead of the rear one, the left one left of the right one.
    assert (cams["front"][:, 0] > cams["rear"][:, 0]).all() and (cams["left"][:, 1] > cams["right"][:, 1]).all()
    files = write_episode(ep, tmp_path, VEHICLE.sha256, 0)
    assert sorted(files.videos) == sorted([*names, "surround"])  # and the rig's tiled video
    assert all(p.is_file() and p.stat().st_size > 0 for p in files.videos.values())


def test_the_base_passes_through_every_waypoint_and_stays_in_the_aisle():
    for manifest in (VEHICLE, CONTROL):
        ep = rollout(manifest, manifest.seed, record=())
        assert ep.success, (manifest.name, ep.reason)
        xy = ep.joint_pos[:, :2]
        path = build_scene(manifest, manifest.seed).path  # the waypoints as this seed moved them
        for point in path:
            assert np.linalg.norm(xy - point, axis=1).min() < 0.2, (manifest.name, point)
        # No overshoot past the widest waypoint: the base never drifts towards the racks.
        widest = max(abs(y) for _, y in path)
        assert np.abs(xy[:, 1]).max() < widest + 0.05


def _yaw(xmat: np.ndarray) -> float:
    """Heading about world z of a MuJoCo camera frame (it looks along its -z axis)."""
    look = -xmat.reshape(3, 3)[:, 2]
    return float(np.arctan2(look[1], look[0]))


def test_the_camera_control_action_is_the_cameras_motion():
    seen: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {c.name: [] for c in CONTROL.cameras}

    def on_frame(scene, renderer, data, camera, angles):
        cam = scene.model.camera(camera).id
        seen[camera].append((data.cam_xpos[cam].copy(), data.cam_xmat[cam].copy()))

    ep = rollout(CONTROL, CONTROL.seed, on_frame=on_frame)
    assert ep.action.shape == (ep.steps, 3)  # [vx, vy, wz] of the base that carries the cameras
    dt = 1.0 / ep.control_hz
    # Integrated, the commanded twist is where the cameras went and how they turned: the servos
    # run about 1 % below their command and lag it while accelerating.
    yaw = np.cumsum(ep.action[:, 2]) * dt
    centre = np.cumsum(ep.action[:, :2], axis=0) * dt
    driven = np.abs(np.diff(ep.joint_pos[:, :2], axis=0)).sum()
    for cam in CONTROL.cameras:
        at = np.searchsorted(ep.time, ep.frame_time[cam.name])[1:] - 1
        pos = np.array([p for p, _ in seen[cam.name]])
        heading = np.unwrap([_yaw(m) for _, m in seen[cam.name]])
        turned = heading[1:] - heading[0]
        assert np.degrees(np.ptp(heading)) > 45  # the rig turns through the slalom
        assert np.abs(np.degrees(turned - yaw[at])).max() < 3.0, cam.name
        # The camera rides at its mount offset, turned by the base's yaw, about the base's centre.
        c, s_ = np.cos(yaw[at]), np.sin(yaw[at])
        offset = np.column_stack([c * cam.position[0] - s_ * cam.position[1], s_ * cam.position[0] + c * cam.position[1]])
        moved = pos[1:, :2] - pos[0, :2]
        commanded = centre[at] + offset - np.asarray(cam.position[:2])
        assert np.abs(moved - commanded).max() < 0.04 * driven, cam.name
        assert np.ptp(pos[:, 1]) > 0.5  # the slalom moves the cameras sideways too


def test_each_seed_commands_its_own_trajectory_inside_the_aisle():
    paths = [build_scene(CONTROL, seed).path for seed in range(4)]
    assert all(p.shape == (len(CONTROL.task.waypoints), 2) for p in paths)
    jitter = CONTROL.task.waypoint_jitter_m
    for p in paths:
        assert np.abs(p - np.array(CONTROL.task.waypoints)).max() <= jitter + 1e-9
    assert min(np.abs(a - b).max() for i, a in enumerate(paths) for b in paths[i + 1:]) > 0.01
    assert np.array_equal(build_scene(CONTROL, 2).path, paths[2])  # the seed decides it
    # Without the jitter the manifest's waypoints are driven as written, whatever the seed.
    still = VEHICLE.model_copy(update={"task": VEHICLE.task.model_copy(update={"waypoint_jitter_m": 0.0})})
    assert np.array_equal(build_scene(still, 3).path, np.array(VEHICLE.task.waypoints))


def test_without_waypoints_the_aisle_drive_is_as_before():
    rig = load(MANIFESTS / "mobile_rig_aisle.yaml")
    assert not rig.task.waypoints and drive_path(rig).tolist() == [[AISLE_GOAL_X, 0.0]]
    scene = build_scene(rig, rig.seed)
    assert scene.goal.tolist() == [AISLE_GOAL_X, 0.0, 0.0]
    control = build_scene(CONTROL, CONTROL.seed)
    assert control.goal.tolist() == [*control.path[-1], 0.0] and scene.path is None


def test_with_repeat_the_base_drives_the_path_back_home():
    scene = build_scene(CONTROL, CONTROL.seed)
    sim = Simulation(scene, CONTROL.seed, repeat=True)
    xs = []
    for _ in range(int(2.2 * CONTROL.horizon_s * 50)):
        sim.advance()
        xs.append(sim.data.qpos[sim.base_qadr].copy())
    xs = np.array(xs)
    far = int(np.argmax(xs[:, 0]))
    assert np.linalg.norm(xs[far] - CONTROL.task.waypoints[-1]) < 0.2
    assert np.linalg.norm(xs[far:], axis=1).min() < 0.2  # and back to the start
