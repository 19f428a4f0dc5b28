"""Scene building: cameras where the manifest puts them, seeded layout, clear errors."""

import re

import numpy as np
import pytest

import tasks.sim  # noqa: F401  (MUJOCO_GL before mujoco)
import mujoco
from schemas.manifest import Camera, Embodiment
from tasks.manifests import load
from tasks.sim.render import MultiCameraRenderer
from tasks.sim.scene import build_scene, look_quat

from tests.support import MANIFESTS, SHARED_DATA

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


# -- object names: every body the scene adds itself is a name the manifest contract reserves --
def test_every_body_the_scene_adds_is_reserved_for_it():
    from schemas.manifest import SCENE_BODIES
    from schemas.manifest import Distractors, ForkliftCrossing, Occluder

    every = (Distractors(count=50), ForkliftCrossing(), Occluder())
    for name in ("bin_pick_dim_forklift.yaml", "conveyor_push.yaml", "mobile_rig_aisle.yaml"):
        manifest = load(MANIFESTS / name)
        stressors = every if manifest.embodiment.kind == "arm" else every[:2]
        task = manifest.task.model_copy(update={"objects": ("package", "box", "crate")})
        scene = build_scene(manifest.model_copy(update={"stressors": stressors, "task": task}), 0)
        bodies = {scene.model.body(i).name for i in range(scene.model.nbody)}
        ours = set(scene.objects[:len(task.objects)])
        assert ours == {"package", "box_1", "crate_2"}
        assert all(SCENE_BODIES.fullmatch(b) for b in bodies - ours), sorted(bodies - ours)


# -- robot files: everything an MJCF makes MuJoCo read lies inside WORLDLINE_ROBOTS_ROOT --------
ARM_MANIFEST = load(MANIFESTS / "bin_pick_dim_forklift.yaml").model_copy(
    update={"embodiment": Embodiment(kind="arm", robot="ur5e", mjcf="arm/arm.xml")})


def _robots(tmp_path, monkeypatch, arm_xml: str, files: dict[str, str] | None = None):
    """A robots root holding arm/arm.xml and ``files`` (relative to the root), and a secret file
    outside it; WORLDLINE_ROBOTS_ROOT points at the root."""
    root, outside = tmp_path / "robots", tmp_path / "outside"
    (root / "arm").mkdir(parents=True)
    outside.mkdir()
    (outside / "secret.xml").write_text("<mujoco><worldbody><body name='stolen'/></worldbody></mujoco>")
    (outside / "secret.stl").write_text("solid x\nendsolid x\n")
    (root / "arm" / "arm.xml").write_text(arm_xml.format(outside=outside))
    for name, text in (files or {}).items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text.format(outside=outside))
    monkeypatch.setenv("WORLDLINE_ROBOTS_ROOT", str(root))
    return root, outside


def _refused(match: str) -> None:
    from tasks.sim.scene import SimConfig, check_assets

    with pytest.raises(FileNotFoundError) as info:
        check_assets(ARM_MANIFEST, SimConfig(gripper_mjcf=None))
    msg = str(info.value)
    assert msg.startswith("embodiment.mjcf 'arm/arm.xml': ") and "\n" not in msg, msg
    assert re.search(match, msg), msg


@pytest.mark.parametrize("linked", ["file", "folder"])
def test_an_mjcf_reached_through_a_symlink_out_of_the_root_is_refused(tmp_path, monkeypatch, linked):
    root, outside = _robots(tmp_path, monkeypatch, "<mujoco/>")
    (outside / "arm.xml").write_text("<mujoco/>")
    if linked == "file":
        (root / "arm" / "arm.xml").unlink()
        (root / "arm" / "arm.xml").symlink_to(outside / "arm.xml")
    else:
        (root / "arm" / "arm.xml").unlink()
        (root / "arm").rmdir()
        (root / "arm").symlink_to(outside)
    _refused(rf"resolves to {re.escape(str(outside / 'arm.xml'))}, outside the robots root {re.escape(str(root))}")


@pytest.mark.parametrize("include", ["{outside}/secret.xml", "../../outside/secret.xml", "link.xml", "parts/inner.xml"])
def test_an_include_out_of_the_root_is_refused(tmp_path, monkeypatch, include):
    root, outside = _robots(tmp_path, monkeypatch, f'<mujoco><include file="{include}"/></mujoco>',
                            {"arm/parts/inner.xml": '<mujoco><include file="../../outside/secret.xml"/></mujoco>'})
    (root / "arm" / "link.xml").symlink_to(outside / "secret.xml")
    _refused(r"<include file=.*> in arm/(arm|parts/inner).xml resolves to .*outside/secret.xml, "
             r"outside the robots root")


@pytest.mark.parametrize("arm_xml", [
    '<mujoco><asset><mesh file="../../outside/secret.stl"/></asset></mujoco>',
    '<mujoco><compiler meshdir="{outside}"/><asset><mesh file="secret.stl"/></asset></mujoco>',
    '<mujoco><compiler assetdir="../../outside"/><asset><hfield file="secret.png" size="1 1 1 1"/></asset></mujoco>',
    '<mujoco><compiler texturedir="../.."/><asset><texture type="cube" fileright="outside/x.png"/></asset></mujoco>',
    '<mujoco><asset><skin file="{outside}/secret.skn"/></asset></mujoco>',
    '<mujoco><include file="parts.xml"/><asset><mesh file="m.stl"/></asset></mujoco>',  # meshdir set in the include
])
def test_an_asset_file_out_of_the_root_is_refused(tmp_path, monkeypatch, arm_xml):
    _robots(tmp_path, monkeypatch, arm_xml, {"arm/parts.xml": '<mujoco><compiler meshdir="{outside}"/></mujoco>'})
    _refused(r"<(mesh|hfield|texture|skin) file\w*=.*> in arm/arm.xml resolves to .*, outside the robots root")


def test_an_mjcf_with_a_doctype_is_refused_unread(tmp_path, monkeypatch):
    _robots(tmp_path, monkeypatch, '<!DOCTYPE mujoco [<!ENTITY x SYSTEM "file://{outside}/secret.xml">]>'
                                   '<mujoco model="&x;"/>')
    _refused(r"arm/arm.xml: declares a DOCTYPE")


def test_an_mjcf_whose_files_stay_inside_the_root_passes(tmp_path, monkeypatch):
    from tasks.sim.scene import SimConfig, check_assets

    root, _ = _robots(tmp_path, monkeypatch, '<mujoco><compiler meshdir="assets"/><include file="parts.xml"/>'
                                             '<asset><mesh file="m.stl"/></asset></mujoco>',
                      {"arm/parts.xml": '<mujoco><include file="more.xml"/></mujoco>', "arm/more.xml": "<mujoco/>"})
    (root / "shared").mkdir()
    (root / "arm" / "assets").symlink_to(root / "shared")  # a link that stays inside is fine
    check_assets(ARM_MANIFEST, SimConfig(gripper_mjcf=None))


@pytest.mark.skipif(not (SHARED_DATA / "robots").is_dir(), reason="no shared robots")
def test_the_shipped_robots_pass(monkeypatch):
    from tasks.sim.scene import SimConfig, check_assets

    monkeypatch.setenv("WORLDLINE_ROBOTS_ROOT", str(SHARED_DATA / "robots"))
    ur5e = ARM_MANIFEST.model_copy(update={"embodiment": Embodiment(kind="arm", robot="ur5e",
                                                                      mjcf="universal_robots_ur5e/ur5e.xml")})
    check_assets(ur5e, SimConfig())
