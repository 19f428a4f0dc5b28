"""Multi-view and camera-control manifests (issue 33): cameras that repeat a name or a pose, and
waypoints that leave the aisle, are refused with one line naming the field; existing hashes hold."""

import copy
import json

import pytest
import yaml
from pydantic import ValidationError

from schemas.manifest import AISLE_HALF_WIDTH_M, AISLE_X_M, FieldError, ScenarioManifest
from tasks.manifests import ManifestError, load, parse_text

from tests.support import MANIFESTS

VEHICLE = load(MANIFESTS / "vehicle_multiview.yaml").model_dump(mode="json")
CONTROL = load(MANIFESTS / "camera_control_aisle.yaml").model_dump(mode="json")

# The shipped manifests' hashes before the waypoints field existed: an empty field is left out
# of the dump, so none of them may change.
PINNED = {
    "bin_pick.yaml": "12e05f9134e5ae09afc94c99942ce11e4c5d9bf8ce5475461714ae9fb3616407",
    "bin_pick_dim_forklift.yaml": "0effe572db396b611e87a01ea880226ee1f38b47dbeff8cfe5791ebcac61eed2",
    "conveyor_push.yaml": "f0b4ba56b52911cd9a95a7e649326741e3003cc6e170a6c3560438c4a0c7440e",
    "mobile_rig_aisle.yaml": "f2ab90c5fd46709ae1f773a646c27d3ae1d59f53e55ef3410e2e677543ac814f",
    "push_closeup.yaml": "0dda9eb4335b9fe3a5013bbfb5285a858c623c10dae3594758d10c6943203ff9",
    "push_closeup_noisy.yaml": "95d3413f073ff3428af6707eb7b4820014d0ba627d2abc14e7d7c51649da4298",
    "push_closeup_pair.yaml": "c2d5b714b10d646c0527cf0025d5923a571f21abfb571fdd5d5495f603dc1048",
}


def _text(body: dict) -> str:
    # Through JSON: lists two cameras share would become YAML aliases, which manifests refuse.
    return yaml.safe_dump(json.loads(json.dumps(body)), sort_keys=False)


def _refusal(body: dict) -> str:
    """The one line parse_text refuses the body with."""
    with pytest.raises(ManifestError) as caught:
        parse_text(_text(body), "bad.yaml")
    line = str(caught.value)
    assert "\n" not in line
    return line


@pytest.mark.parametrize("name, digest", sorted(PINNED.items()))
def test_existing_manifest_hashes_are_unchanged(name, digest):
    manifest = load(MANIFESTS / name)
    assert manifest.sha256 == digest
    assert "waypoints" not in manifest.model_dump(mode="json")["task"]


def test_the_new_rigs_load_with_body_mounted_cameras_and_a_path():
    vehicle = ScenarioManifest.model_validate(VEHICLE)
    assert {c.name for c in vehicle.cameras} >= {"front", "rear", "left", "right"}
    assert all(c.mount == "vehicle" for c in vehicle.cameras)
    assert vehicle.embodiment.kind == "mobile" and vehicle.task.kind == "drive" and vehicle.task.waypoints
    control = ScenarioManifest.model_validate(CONTROL)
    assert control.task.waypoints and all(c.mount == "vehicle" for c in control.cameras)


def test_waypoints_are_meaning_and_change_the_hash():
    moved = copy.deepcopy(CONTROL)
    moved["task"]["waypoints"][-1] = [3.7, 0.0]
    assert parse_text(_text(moved)).sha256 != parse_text(_text(CONTROL)).sha256
    assert parse_text(_text(CONTROL)) == ScenarioManifest.model_validate(CONTROL)  # round trip keeps them


def test_a_repeated_camera_name_is_one_line_naming_the_field():
    body = copy.deepcopy(VEHICLE)
    body["cameras"][3]["name"] = "front"
    line = _refusal(body)
    assert line == "bad.yaml: cameras.3.name: 'front' is also the name of cameras.0; camera names must differ"
    with pytest.raises(ValidationError, match=r"cameras\.3\.name: 'front' is also the name of cameras\.0"):
        ScenarioManifest.model_validate(body)


@pytest.mark.parametrize("look_at", [None, "farther"])
def test_a_repeated_camera_pose_is_one_line_naming_the_field(look_at):
    body = copy.deepcopy(VEHICLE)
    twin = {**body["cameras"][0], "name": "front_b", "resolution": [64, 64]}
    if look_at == "farther":  # further along the same ray: the same view direction
        p, t = twin["position"], twin["look_at"]
        twin["look_at"] = [pi + 2 * (ti - pi) for pi, ti in zip(p, t)]
    body["cameras"].insert(2, twin)
    line = _refusal(body)
    assert line.startswith("bad.yaml: cameras.2.position: 'front_b' has the pose of cameras.0 ('front')"), line
    with pytest.raises(ValidationError, match=r"cameras\.2\.position: 'front_b' has the pose of cameras\.0"):
        ScenarioManifest.model_validate(body)


@pytest.mark.parametrize("change", [
    {"position": [0.25, 0.01, 0.55]},  # 1 cm beside it
    {"look_at": [2.0, 0.1, 0.45]},  # turned a little
    {"mount": "world"},  # the same numbers in the world frame: a camera that stays behind
])
def test_cameras_at_different_poses_pass(change):
    body = copy.deepcopy(VEHICLE)
    body["cameras"].append({**body["cameras"][0], "name": "front_b", **change})
    assert len(parse_text(_text(body)).cameras) == len(VEHICLE["cameras"]) + 1


@pytest.mark.parametrize("index, point", [
    (1, [1.8, AISLE_HALF_WIDTH_M + 0.05]),  # into the racks on the left
    (0, [0.8, -1.5]),  # through the racks on the right
    (3, [AISLE_X_M[1] + 0.5, 0.0]),  # past the end of the aisle
    (2, [AISLE_X_M[0] - 1.0, 0.0]),  # behind its start
])
def test_a_path_that_leaves_the_aisle_is_one_line_naming_the_field(index, point):
    body = copy.deepcopy(CONTROL)
    body["task"]["waypoints"][index] = point
    line = _refusal(body)
    assert line.startswith(f"bad.yaml: task.waypoints.{index}: ({point[0]:g}, {point[1]:g}) leaves the aisle"), line
    with pytest.raises(ValidationError, match=rf"waypoints\.{index}: \({point[0]:g}, {point[1]:g}\) leaves the aisle"):
        ScenarioManifest.model_validate(body)


def test_waypoints_belong_to_a_drive():
    body = load(MANIFESTS / "conveyor_push.yaml").model_dump(mode="json")
    body["task"]["waypoints"] = [[0.5, 0.0]]
    assert _refusal(body).startswith("bad.yaml: task.waypoints: only a drive task follows waypoints, not 'push'")


def test_field_error_reads_as_one_line_anywhere():
    error = FieldError("cameras.1.name", "problem")
    assert str(error) == "cameras.1.name: problem" and isinstance(error, ValueError)


def test_the_camera_control_rig_turns_and_jitters_its_path():
    control = ScenarioManifest.model_validate(CONTROL)
    assert control.embodiment.action_space == "twist" and control.task.waypoint_jitter_m > 0
    for name in PINNED:
        assert "waypoint_jitter_m" not in load(MANIFESTS / name).model_dump(mode="json")["task"]
    wider = copy.deepcopy(CONTROL)
    wider["task"]["waypoint_jitter_m"] = 0.2
    assert parse_text(_text(wider)).sha256 != parse_text(_text(CONTROL)).sha256


def test_a_twist_belongs_to_a_base():
    body = load(MANIFESTS / "conveyor_push.yaml").model_dump(mode="json")
    body["embodiment"]["action_space"] = "twist"
    assert _refusal(body).startswith("bad.yaml: embodiment.action_space: twist ([vx, vy, wz]) drives a mobile base"), \
        _refusal(body)


@pytest.mark.parametrize("jitter, problem", [
    (-0.1, "greater than or equal to 0"),
    (0.6, "less than or equal to 0.5"),
])
def test_a_bad_waypoint_jitter_is_one_line_naming_the_field(jitter, problem):
    body = copy.deepcopy(CONTROL)
    body["task"]["waypoint_jitter_m"] = jitter
    line = _refusal(body)
    assert "task.waypoint_jitter_m" in line and problem in line, line


def test_waypoint_jitter_needs_waypoints():
    body = load(MANIFESTS / "mobile_rig_aisle.yaml").model_dump(mode="json")
    body["task"]["waypoint_jitter_m"] = 0.1
    assert _refusal(body).startswith("bad.yaml: task.waypoint_jitter_m: jitters the task's waypoints, and there are none")


def test_a_rig_tiles_named_cameras_of_one_resolution_and_rate():
    vehicle = ScenarioManifest.model_validate(VEHICLE)
    rig = vehicle.rig("surround")
    assert rig.layout == (("front", "right"), ("left", "rear")) and rig.cameras == ["front", "right", "left", "rear"]
    assert vehicle.rig("roof") is None
    # No rigs leaves the field out of the dump, so a manifest without one keeps its hash.
    bare = {k: v for k, v in VEHICLE.items() if k != "rigs"}
    assert "rigs" not in ScenarioManifest.model_validate(bare).model_dump(mode="json")


@pytest.mark.parametrize("layout, said", [
    ([["front", "right"], ["left"]], "rigs.0.layout: Value error, rows of [1, 2] cameras"),
    ([["front", "front"]], "camera(s) front appear more than once"),
    ([["front"]], "a rig tiles at least two cameras"),
])
def test_a_bad_rig_layout_is_refused_naming_the_field(layout, said):
    body = copy.deepcopy(VEHICLE)
    body["rigs"][0]["layout"] = layout
    line = _refusal(body)
    assert said in line, line
