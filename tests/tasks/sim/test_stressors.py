"""Every stressor is a real change to the rendered scene or to the outcome."""

import numpy as np
import pytest

from schemas.manifest import Appearance, DimLight, ForkliftCrossing, Occluder
from tasks.manifests import load
from tasks.sim.episode import rollout
from tasks.sim.scene import build_scene

from tests.support import MANIFESTS


@pytest.fixture(scope="module")
def base():
    m = load(MANIFESTS / "bin_pick_dim_forklift.yaml")
    cams = (m.cameras[0].model_copy(update={"resolution": (64, 64)}),)
    return m.model_copy(update={"horizon_s": 4.0, "cameras": cams, "stressors": ()})


@pytest.fixture(scope="module")
def plain(base):
    return rollout(base, 1)


def _with(base, *stressors):
    return base.model_copy(update={"stressors": stressors})


@pytest.mark.parametrize("path", sorted(MANIFESTS.glob("*.yaml")), ids=lambda p: p.name)
def test_every_shipped_manifest_builds(path):
    scene = build_scene(load(path), 0)
    assert scene.model.ncam == len(load(path).cameras)


def test_unstressed_bin_pick_succeeds(plain):
    assert plain.success and not plain.estop.any(), plain.reason


def test_dim_light_darkens_the_scene(base, plain):
    dim = rollout(_with(base, DimLight(lux=30)), 1)
    assert dim.frames["front_left"].mean() < 0.3 * plain.frames["front_left"].mean()


def test_forklift_through_the_workcell_is_an_emergency_stop(base):
    hit = rollout(_with(base, ForkliftCrossing(speed_mps=1.0, lane_m=0.0, start_s=0.0)), 1)
    assert not hit.success and hit.estop.any() and "forklift" in hit.reason


def test_forklift_in_its_aisle_crosses_the_view_without_stopping_the_arm(base, plain):
    aisle = rollout(_with(base, ForkliftCrossing(speed_mps=1.5, lane_m=-0.9, start_s=0.0)), 1)
    assert aisle.success and not aisle.estop.any()
    changed = np.abs(aisle.frames["front_left"].astype(int) - plain.frames["front_left"]).mean(axis=(1, 2, 3))
    assert changed.max() > 2 * changed.min() + 1  # it enters and leaves: the difference moves with it


def test_occluder_changes_the_view(base, plain):
    hidden = rollout(_with(base, Occluder(coverage=0.6)), 1)
    diff = np.abs(hidden.frames["front_left"][0].astype(int) - plain.frames["front_left"][0]).max(axis=-1)
    assert (diff > 10).sum() >= 20  # a box stands in front of the package (a small target at 64x64)


def test_appearance_follows_the_seed(base):
    styled = _with(base, Appearance(colour_jitter=0.8))
    a, b, c = rollout(styled, 1), rollout(styled, 1), rollout(styled, 2)
    assert np.array_equal(a.frames["front_left"], b.frames["front_left"])
    assert not np.array_equal(a.frames["front_left"][0], c.frames["front_left"][0])


def test_mobile_rig_drives():
    m = load(MANIFESTS / "mobile_rig_aisle.yaml")
    ep = rollout(m.model_copy(update={"horizon_s": 2.0}), 0)
    assert set(ep.frames) == {"front", "rear"} and ep.frames["front"].shape[1:] == (96, 160, 3)
    assert np.abs(np.diff(ep.joint_pos[:, :2], axis=0)).sum() > 0.1  # the base moved


def test_camera_jitter_moves_the_view_frame_to_frame(base):
    from schemas.manifest import CameraJitter

    still = rollout(_with(base, DimLight(lux=500)), 1).frames["front_left"]
    shaky = rollout(_with(base, DimLight(lux=500), CameraJitter(amplitude_deg=3.0, frequency_hz=6.0)), 1).frames["front_left"]
    assert np.array_equal(still[0].shape, shaky[0].shape)
    assert np.abs(shaky.astype(int) - still).mean() > 2


def test_distractors_are_extra_bodies(base):
    from schemas.manifest import Distractors

    plain = build_scene(base, 1)
    busy = build_scene(_with(base, Distractors(count=4)), 1)
    assert busy.model.nbody >= plain.model.nbody + 4


def test_menagerie_ur5e_with_robotiq_gripper(base, shared_data):
    from schemas.manifest import Embodiment
    from tasks.sim.scene import SimConfig

    ur5e = base.model_copy(update={"horizon_s": 0.5,
                                   "embodiment": Embodiment(kind="arm", robot="ur5e", mjcf="universal_robots_ur5e/ur5e.xml")})
    config = SimConfig(robots_root=shared_data / "robots")
    scene = build_scene(ur5e, 0, config)
    names = {scene.model.body(i).name for i in range(scene.model.nbody)}
    assert any("wrist_3" in n for n in names) and any("pad" in n or "driver" in n for n in names)
    ep = rollout(ur5e, 0, config)
    assert ep.frames["front_left"].shape[0] == 15 and ep.joint_pos.shape[1] >= 6


def _package_pixels(manifest, seed=1):
    import mujoco

    from tasks.sim.render import MultiCameraRenderer

    scene = build_scene(manifest, seed)
    data = mujoco.MjData(scene.model)
    data.qpos[:] = scene.initial_qpos
    mujoco.mj_forward(scene.model, data)
    cam = manifest.cameras[0]
    geom = scene.model.geom(f"{scene.objects[0]}_geom").id
    with MultiCameraRenderer(scene.model, {cam.name: (256, 256)}) as renderer:
        return int((renderer.segment(data, cam.name) == geom).sum())


@pytest.mark.parametrize("coverage", [0.3, 0.7])
def test_occluder_hides_about_its_coverage_of_the_package(base, coverage):
    big = base.model_copy(update={"cameras": (base.cameras[0].model_copy(update={"resolution": (256, 256)}),)})
    seen = _package_pixels(big)
    hidden = _package_pixels(_with(big, Occluder(coverage=coverage)))
    assert seen > 200  # the target is in view to begin with
    # Coverage is of the package's projected width, so the pixel share matches only roughly.
    assert 1 - hidden / seen == pytest.approx(coverage, abs=0.1)


def test_camera_jitter_moves_pictures_not_physics(base):
    from schemas.manifest import CameraJitter

    short = base.model_copy(update={"horizon_s": 1.0})
    still = rollout(short, 3)
    shaky = rollout(_with(short, CameraJitter(amplitude_deg=2.0, frequency_hz=5.0)), 3)
    assert np.array_equal(still.action, shaky.action) and np.array_equal(still.joint_pos, shaky.joint_pos)
    assert not np.array_equal(still.frames["front_left"], shaky.frames["front_left"])


def test_brighter_light_brightens_monotonically(base):
    short = base.model_copy(update={"horizon_s": 0.2})
    means = [rollout(_with(short, DimLight(lux=lux)), 1).frames["front_left"].mean() for lux in (25, 100, 500)]
    assert means[0] < means[1] < means[2]
