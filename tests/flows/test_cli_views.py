"""Issue 33 through the CLI: the multi-view vehicle rig simulates with one video per camera; a
rig whose cameras repeat a name or a pose, or whose path leaves the aisle, is refused with exit 2
and one line naming the field, before anything is written."""

import json

import pytest
import yaml
from typer.testing import CliRunner

from tasks.manifests import load

from tests.support import MANIFESTS

runner = CliRunner()
VEHICLE = MANIFESTS / "vehicle_multiview.yaml"
CONTROL = MANIFESTS / "camera_control_aisle.yaml"


def _repeated_name(body):
    body["cameras"][3]["name"] = "front"
    return "cameras.3.name: 'front' is also the name of cameras.0"


def _repeated_pose(body):
    body["cameras"].insert(2, {**body["cameras"][0], "name": "front_b"})
    return "cameras.2.position: 'front_b' has the pose of cameras.0 ('front')"


def _off_the_aisle(body):
    body["task"]["waypoints"][1] = [1.8, -1.2]
    return "task.waypoints.1: (1.8, -1.2) leaves the aisle"


def _rig_of_a_missing_camera(body):
    body["rigs"][0]["layout"][1][1] = "roof"
    return "rigs.0.layout.1.1: 'roof' is not one of the manifest's cameras"


def _rig_named_as_a_camera(body):
    body["rigs"][0]["name"] = "left"
    return "rigs.0.name: 'left' is also the name of a camera"


def _rig_of_unlike_cameras(body):
    body["cameras"][2]["resolution"] = [96, 64]
    return "rigs.0.layout.1.1: 'rear' records 96x64 at 10 fps, 'front' 64x64 at 10"


@pytest.mark.parametrize("source, spoil", [(VEHICLE, _repeated_name), (VEHICLE, _repeated_pose),
                                           (CONTROL, _off_the_aisle), (VEHICLE, _rig_of_a_missing_camera),
                                           (VEHICLE, _rig_named_as_a_camera), (VEHICLE, _rig_of_unlike_cameras)],
                         ids=["repeated-name", "repeated-pose", "off-the-aisle", "rig-missing-camera",
                              "rig-named-as-camera", "rig-unlike-cameras"])
def test_a_bad_rig_is_one_line_naming_the_field_exit_2(tmp_path, data_root, source, spoil):
    from flows.cli import app

    body = json.loads(json.dumps(load(source).model_dump(mode="json")))
    said = spoil(body)
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(json.loads(json.dumps(body)), sort_keys=False))  # no shared lists: no aliases
    for args in (["register", str(bad)], ["simulate", str(bad), "--episodes", "1"], ["manifest", "validate", str(bad)]):
        result = runner.invoke(app, args)
        lines = [line for line in result.output.splitlines() if line.strip()]
        assert result.exit_code == 2 and len(lines) == 1, (args, result.output)
        assert str(bad) in lines[0] and said in lines[0], (args, lines[0])
    assert not (data_root / "lineage.duckdb").exists() and not (data_root / "episodes").exists()


def test_simulating_the_vehicle_writes_one_video_per_camera_and_its_rig(prefect_harness, data_root):
    from flows.cli import app

    result = runner.invoke(app, ["simulate", str(VEHICLE), "--episodes", "2"])
    assert result.exit_code == 0, result.output
    episodes = sorted((data_root / "episodes").glob("*/episode_*"))
    assert len(episodes) == 2
    names = sorted(c.name for c in load(VEHICLE).cameras)
    for folder in episodes:
        assert sorted(p.stem for p in folder.glob("*.mp4")) == sorted([*names, "surround"])
        meta = json.loads((folder / "meta.json").read_text())
        assert sorted(meta["cameras"]) == names and meta["rigs"] == ["surround"]  # a rig is not a camera
        # The rig's video is its four views tiled, as many frames as each.
        from tasks.sim.rigs import untile
        from tasks.video import read_frames

        tiled, front = read_frames(folder / "surround.mp4"), read_frames(folder / "front.mp4")
        assert tiled.shape == (len(front), 128, 128, 3)
        assert abs(untile(tiled, [["front", "right"], ["left", "rear"]])["front"].astype(float) - front).mean() < 4
