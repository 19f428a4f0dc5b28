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


def _objects(*objects):
    return _with(task={**BASE["task"], "objects": list(objects)})


@pytest.mark.parametrize("objects, problem", [
    ((), "at least one object"),  # the scene's first object is the task's target (IndexError before)
    (("package", "distractor"), "'distractor_1'"),  # the distractors stressor's own first bodies
    (("distractor_3",), "'distractor_3'"),
    (("package", "package"), "repeat"),
    (("Package", "package"), "repeat"),  # one body name once lower-cased
    (("package_1", "package"), "both become body 'package_1'"),
    (("ee",), "'ee'"),
    (("forklift",), "'forklift'"),
    (("arm_link2",), "'arm_link2'"),
    (("base",), "'base'"),
    (("robot_base",), "'robot_base'"),  # an MJCF arm's bodies are all robot_* or gripper_*
    (("gripper_pad",), "'gripper_pad'"),
    (("world",), "'world'"),
])
def test_object_lists_the_scene_cannot_build_are_refused(objects, problem):
    with pytest.raises(ValidationError) as info:
        _objects(*objects)
    assert "task.objects" in str(info.value) and problem in str(info.value)


@pytest.mark.parametrize("objects", [("package",), ("package", "box", "crate"), ("distractor",), ("Package",)])
def test_object_lists_with_distinct_free_names_pass(objects):
    assert _objects(*objects).task.objects == objects


def test_object_bodies_are_named_as_the_scene_names_them():
    from schemas.manifest import object_body_name

    assert [object_body_name(o, i) for i, o in enumerate(("Big Box", "", "x" * 30))] == \
        ["big_box", "object_1", "x" * 24 + "_2"]


def test_the_manifest_hash_is_computed_once_and_a_changed_copy_has_its_own():
    from schemas.hashing import content_hash
    from schemas.manifest import VOLATILE_FIELDS, manifest_hash

    manifest = load(REPO / "manifests" / "conveyor_push.yaml")
    assert manifest.sha256 == manifest_hash(manifest) == content_hash(
        manifest.model_dump(mode="json", exclude=set(VOLATILE_FIELDS)))
    assert manifest.sha256 is manifest.sha256 and "sha256" not in manifest.model_dump()
    changed = manifest.model_copy(update={"seed": manifest.seed + 1})
    assert changed.sha256 != manifest.sha256
    assert changed.sha256 == ScenarioManifest.model_validate(changed.model_dump()).sha256


@pytest.mark.parametrize("horizon_s, problem", [
    (0.001, "0.001 s gives camera 'front_left' (cameras.0, 30 fps) 0 frame(s)"),  # crashed simulate's writer
    (0.05, "0.05 s gives camera 'front_left' (cameras.0, 30 fps) 1 frame(s)"),
])
def test_a_horizon_under_two_frames_of_a_camera_is_refused_in_one_line(horizon_s, problem):
    from tasks.manifests import ManifestError, parse_text

    import yaml

    with pytest.raises(ManifestError) as info:
        parse_text(yaml.safe_dump({**BASE, "horizon_s": horizon_s}), "m.yaml")
    line = str(info.value)
    assert "\n" not in line and line.startswith("m.yaml: horizon_s: ") and problem in line
    assert "at least 2, so horizon_s must be at least 0.0666667 s" in line


def test_the_horizon_rule_counts_frames_as_simulate_records_them():
    from schemas.manifest import CONTROL_HZ, camera_frames
    from tasks.sim.scene import SimConfig

    assert CONTROL_HZ == SimConfig().control_hz
    assert camera_frames(0.2, 10) == 2 and camera_frames(0.19, 10) == 1 and camera_frames(0.1, 30) == 3
    one_camera = {**BASE, "cameras": [BASE["cameras"][0]], "stressors": [], "rigs": []}
    assert _with(**{**one_camera, "horizon_s": 2 / 30}).horizon_s == 2 / 30  # exactly two frames pass
    fast = {**one_camera, "cameras": [{**BASE["cameras"][0], "fps": 240}]}
    assert _with(**{**fast, "horizon_s": 0.02}).horizon_s == 0.02  # one control step
    with pytest.raises(ValidationError, match="shorter than one control step"):
        _with(**{**fast, "horizon_s": 0.01})  # 2.4 frames, but round(0.01 * 50) == 0 steps


def test_every_shipped_manifest_films_every_camera():
    paths = sorted((REPO / "manifests").glob("*.yaml"))  # manifests/grids holds panel grids, not manifests
    assert len(paths) > 5
    for path in paths:
        load(path)
