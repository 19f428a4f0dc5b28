"""Scene building: cameras where the manifest puts them, seeded layout, clear errors."""

import numpy as np
import pytest

import tasks.sim  # noqa: F401  (MUJOCO_GL before mujoco)
import mujoco
from schemas.manifest import Camera, Embodiment
from tasks.manifests import load
from tasks.sim.render import MultiCameraRenderer
from tasks.sim.scene import build_scene, look_quat

from tests.support import MANIFESTS

SHIPPED = sorted(MANIFESTS.glob("*.yaml"))


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_cameras_match_the_manifest(path):
    manifest = load(path)
    scene = build_scene(manifest, 0)
    m = scene.model
    assert m.ncam == len(manifest.cameras)
    data = mujoco.MjData(m)
    data.qpos[:] = scene.initial_qpos
    mujoco.mj_forward(m, data)
    for cam in manifest.cameras:
        cid = m.camera(cam.name).id
        assert tuple(m.cam_resolution[cid]) == tuple(cam.resolution)
        assert m.cam_fovy[cid] == pytest.approx(cam.fovy_deg)
        parent = m.body(m.cam_bodyid[cid]).name
        assert parent == {"world": "world", "wrist": "ee", "vehicle": "base"}[cam.mount]
        # look_at (in the mount's frame) lies on the camera's optical axis (its -z).
        frame = data.xmat[m.cam_bodyid[cid]].reshape(3, 3)
        target = data.xpos[m.cam_bodyid[cid]] + frame @ np.array(cam.look_at)
        local = data.cam_xmat[cid].reshape(3, 3).T @ (target - data.cam_xpos[cid])
        assert local[2] < 0 and np.hypot(local[0], local[1]) < 1e-6 * max(1.0, -local[2])


def test_frames_have_each_cameras_own_size():
    manifest = load(MANIFESTS / "mobile_rig_aisle.yaml")
    cams = (manifest.cameras[0].model_copy(update={"resolution": (48, 32)}),
            manifest.cameras[1].model_copy(update={"resolution": (20, 40)}))
    scene = build_scene(manifest.model_copy(update={"cameras": cams}), 0)
    data = mujoco.MjData(scene.model)
    mujoco.mj_forward(scene.model, data)
    with MultiCameraRenderer(scene.model, {c.name: c.resolution for c in cams}) as renderer:
        assert renderer.render(data, "front").shape == (32, 48, 3)
        assert renderer.render(data, "rear").shape == (40, 20, 3)


def test_look_quat_points_the_camera_at_the_target():
    for pos, at in [((1.0, 0.5, 0.7), (0.4, 0.0, 0.1)), ((0.45, 0.0, 1.4), (0.45, 0.0, 0.0))]:
        mat = np.zeros(9)
        mujoco.mju_quat2Mat(mat, look_quat(pos, at))
        axis = -mat.reshape(3, 3)[:, 2]
        want = np.subtract(at, pos) / np.linalg.norm(np.subtract(at, pos))
        assert np.allclose(axis, want, atol=1e-9)


def test_layout_follows_the_seed():
    manifest = load(MANIFESTS / "conveyor_push.yaml")
    a, b, c = build_scene(manifest, 5), build_scene(manifest, 5), build_scene(manifest, 6)
    assert np.array_equal(a.initial_qpos, b.initial_qpos) and np.array_equal(a.model.geom_rgba, b.model.geom_rgba)
    assert np.array_equal(a.goal, b.goal)
    assert not np.array_equal(a.initial_qpos, c.initial_qpos)


def test_a_wrist_camera_needs_an_arm():
    manifest = load(MANIFESTS / "mobile_rig_aisle.yaml")
    wrist = Camera(name="wrist", mount="wrist", position=(0, 0, -0.05), look_at=(0, 0, -0.5), resolution=(32, 32))
    with pytest.raises(ValueError, match="mobile-rig-aisle.*wrist"):
        build_scene(manifest.model_copy(update={"cameras": (wrist,)}), 0)


def test_task_must_fit_the_embodiment():
    manifest = load(MANIFESTS / "conveyor_push.yaml")
    with pytest.raises(ValueError, match="conveyor-push.*drive needs mobile"):
        build_scene(manifest.model_copy(update={"embodiment": Embodiment(kind="mobile")}), 0)


def test_missing_robot_mjcf_names_the_file(tmp_path):
    from tasks.sim.scene import SimConfig

    manifest = load(MANIFESTS / "bin_pick_dim_forklift.yaml")
    arm = Embodiment(kind="arm", robot="ur5e", mjcf="nowhere/ur5e.xml")
    with pytest.raises(FileNotFoundError, match="embodiment.mjcf 'nowhere/ur5e.xml': no robot MJCF at"):
        build_scene(manifest.model_copy(update={"embodiment": arm}), 0, SimConfig(robots_root=tmp_path))


def test_robots_resolve_under_worldline_robots_root(tmp_path, monkeypatch):
    from tasks.sim.scene import SimConfig, check_assets

    manifest = load(MANIFESTS / "bin_pick_dim_forklift.yaml")
    arm = manifest.model_copy(update={"embodiment": Embodiment(kind="arm", robot="ur5e", mjcf="ur5e/ur5e.xml")})
    monkeypatch.setenv("WORLDLINE_ROBOTS_ROOT", str(tmp_path))
    assert SimConfig().robots_root == tmp_path
    check_assets(manifest)  # the built-in arm needs no files
    (tmp_path / "ur5e").mkdir()
    (tmp_path / "ur5e" / "ur5e.xml").write_text("<mujoco/>")
    with pytest.raises(FileNotFoundError, match="gripper 'robotiq_2f85/2f85.xml': no robot MJCF at"):
        check_assets(arm)
    check_assets(arm, SimConfig(gripper_mjcf=None))
