"""Every manifest we ship validates (STYLE 10: every shipped config is checked in CI)."""

import pytest

from schemas.manifest import manifest_hash
from tasks.manifests import load

from tests.support import REPO

SHIPPED = sorted((REPO / "manifests").glob("*.yaml"))


def test_at_least_three_manifests_ship():
    assert len(SHIPPED) >= 3


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_shipped_manifest_validates(path):
    m = load(path)
    assert len(manifest_hash(m)) == 64
    assert m.cameras and m.horizon_s > 0


def test_shipped_manifests_are_distinct():
    hashes = {manifest_hash(load(p)) for p in SHIPPED}
    assert len(hashes) == len(SHIPPED)


ARMS = [p for p in SHIPPED if load(p).embodiment.kind == "arm"]


@pytest.mark.parametrize("path", ARMS, ids=lambda p: p.name)
def test_shipped_manifest_has_its_robot_files(path, shared_data):
    """What every simulating command checks first. No shipped manifest names an MJCF yet (they
    use the built-in arm, which needs no files), so each is also checked with the real UR5e from
    ../shared/data/robots put in, and with a robot file that is not there."""
    from schemas.manifest import Embodiment
    from tasks.sim.scene import SimConfig, check_assets

    config = SimConfig(robots_root=shared_data / "robots")
    manifest = load(path)
    check_assets(manifest, config)

    def with_mjcf(mjcf: str):
        arm = Embodiment(kind="arm", robot="ur5e", mjcf=mjcf, action_space=manifest.embodiment.action_space)
        return manifest.model_copy(update={"embodiment": arm})

    check_assets(with_mjcf("universal_robots_ur5e/ur5e.xml"), config)
    with pytest.raises(FileNotFoundError, match=r"^embodiment.mjcf 'universal_robots_ur5e/ur5e_gone.xml': "
                                                r"no robot MJCF at .*universal_robots_ur5e/ur5e_gone.xml"):
        check_assets(with_mjcf("universal_robots_ur5e/ur5e_gone.xml"), config)
