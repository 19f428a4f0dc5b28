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


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_shipped_manifest_has_its_robot_files(path):
    from tasks.sim.scene import check_assets

    check_assets(load(path))  # what every simulating command checks first
