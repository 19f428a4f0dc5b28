import pytest
from pydantic import ValidationError

from schemas.manifest import ScenarioManifest, check_relative_path
from tasks.manifests import load

from tests.support import REPO

BASE = load(REPO / "manifests" / "bin_pick_dim_forklift.yaml").model_dump(mode="json")


def _with(**changes):
    body = {**BASE, **changes}
    return ScenarioManifest.model_validate(body)


@pytest.mark.parametrize("bad", ["../robots/x.xml", "a/../../etc/passwd", "/etc/passwd", "~/x.xml", "C:/x.xml", "a\\..\\..\\b", ""])
def test_paths_may_not_escape(bad):
    with pytest.raises(ValueError):
        check_relative_path(bad)


def test_relative_paths_pass():
    assert check_relative_path("universal_robots_ur5e/ur5e.xml") == "universal_robots_ur5e/ur5e.xml"


@pytest.mark.parametrize("changes", [
    {"horizon_s": float("nan")},
    {"horizon_s": float("inf")},
    {"horizon_s": 1e9},
    {"seed": -1},
    {"cameras": [{**BASE["cameras"][0], "resolution": [100000, 100000]}]},
    {"cameras": [{**BASE["cameras"][0], "fps": 10000}]},
    {"cameras": [{**BASE["cameras"][0], "fps": 0}]},
    {"cameras": [BASE["cameras"][0], BASE["cameras"][0]]},
    {"stressors": [{"kind": "dim_light", "lux": 5}, {"kind": "dim_light", "lux": 9}]},
    {"stressors": [{"kind": "earthquake"}]},
    {"embodiment": {**BASE["embodiment"], "mjcf": "../../etc/passwd"}},
    {"unknown_field": 1},
    {"name": "Has Spaces"},
])
def test_hostile_or_absurd_values_are_refused(changes):
    with pytest.raises(ValidationError):
        _with(**changes)


def test_manifest_is_frozen():
    m = _with()
    with pytest.raises(ValidationError):
        m.seed = 3
