"""The loop flow: worst cells -> derived manifests -> episodes, shards -> post-trained policy
-> the same panel again, all in lineage."""

import json
from pathlib import Path

from typer.testing import CliRunner

from flows.cli import app
from flows.loop import loop
from schemas.manifest import manifest_hash
from schemas.settings import Settings
from tasks.manifests import load
from tasks.policy.bc import TrainConfig, collect, save_checkpoint, train_bc
from warehouse.store import Warehouse

from tests.support import MANIFESTS

GRID = """
name: duo
cells:
  - name: nominal
  - name: jitter
    stressors: [{kind: camera_jitter, amplitude_deg: 2.0, frequency_hz: 5.0}]
episodes: 1
"""


def _manifest(tmp_path: Path) -> Path:
    text = (MANIFESTS / "conveyor_push.yaml").read_text()
    path = tmp_path / "push.yaml"
    path.write_text(text.replace("horizon_s: 5.0", "horizon_s: 3.0").replace("[128, 128]", "[64, 64]"))
    return path


def _bc(tmp_path: Path, manifest: Path) -> Path:
    scenario = load(manifest)
    model, _ = train_bc(collect(scenario, [5]), TrainConfig(steps=20))
    folder = tmp_path / "bc"
    save_checkpoint(model, folder, scenario, TrainConfig(steps=20))
    return folder


def test_loop_derives_trains_and_reevaluates(prefect_harness, data_root, tmp_path):
    manifest, grid = _manifest(tmp_path), tmp_path / "grid.yaml"
    grid.write_text(GRID)
    parent_hash = manifest_hash(load(manifest))
    result = loop(str(manifest), f"bc:{_bc(tmp_path, manifest)}", str(grid), worst=1, new_episodes=2, post_steps=20)

    assert [r["cell"] for r in result["table"]] == ["nominal", "jitter", "all"]
    assert all(r["before"] is not None and r["after"] is not None for r in result["table"])
    (derived,) = result["derived"]
    assert derived["cell"] in {"nominal", "jitter"} and derived["episodes"] == 2
    assert result["shards"], "the derived episodes' videos were curated into shards"

    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, rows = wh.query("SELECT parent_hash FROM manifests WHERE manifest_hash = $d", {"d": derived["manifest_hash"]})
        assert rows == [(parent_hash,)]
        _, rows = wh.query("SELECT relation FROM edges WHERE parent_id = $p AND child_id = $d ORDER BY relation",
                           {"p": parent_hash, "d": derived["manifest_hash"]})
        assert ("derived_from_failure",) in rows
        _, episodes = wh.query("SELECT artifact_id FROM artifacts WHERE kind = 'episode' AND manifest_hash = $d",
                               {"d": derived["manifest_hash"]})
        assert len(episodes) == 2
        _, shards = wh.query("SELECT count(*) FROM artifacts WHERE kind = 'shard' AND manifest_hash = $d",
                             {"d": derived["manifest_hash"]})
        assert shards[0][0] >= 1
        _, edges = wh.query("SELECT parent_id, relation FROM edges WHERE child_id = $c", {"c": result["checkpoint_id"]})
        assert (result["old_checkpoint_id"], "posttrained_from") in edges
        assert {p for p, r in edges if r == "trained_on"} == {e for (e,) in episodes}
        _, kinds = wh.query("SELECT kind FROM artifacts WHERE artifact_id = $c", {"c": result["checkpoint_id"]})
        assert kinds == [("checkpoint",)]
        _, used = wh.query("SELECT parent_id FROM edges WHERE child_id = $e AND relation = 'policy'",
                           {"e": result["after_evaluation_id"]})
        assert used == [(result["checkpoint_id"],)]
    assert (Path(result["checkpoint"]) / "model.safetensors").is_file()

    audit = CliRunner().invoke(app, ["audit", "failure", "--artifact", result["before_evaluation_id"]])
    assert audit.exit_code == 0, audit.output


def test_cli_refuses_before_any_work(data_root, tmp_path):
    result = CliRunner().invoke(app, ["loop", str(MANIFESTS / "mobile_rig_aisle.yaml")])
    assert result.exit_code == 2 and "drives arms" in result.output
    result = CliRunner().invoke(app, ["loop", str(_manifest(tmp_path)), "--policy", "bc:/nowhere"])
    assert result.exit_code == 2 and "not a behaviour-cloning checkpoint" in result.output
    result = CliRunner().invoke(app, ["loop", str(_manifest(tmp_path)), "--policy", "scripted"])
    assert result.exit_code == 2 and "the loop post-trains learned policies" in result.output
    result = CliRunner().invoke(app, ["loop", str(_manifest(tmp_path)), "--policy", "bc:0123456789abcdef"])
    assert result.exit_code == 2 and "no lineage warehouse yet" in result.output
    assert not (data_root / "lineage.duckdb").exists()


def test_the_loop_post_trains_a_vision_policy_on_what_its_cameras_saw(prefect_harness, data_root, tmp_path):
    from tasks.policy import vision, vision_train
    from tasks.policy.vision_obs import ObservationSpec

    manifest, grid = _manifest(tmp_path), tmp_path / "grid.yaml"
    grid.write_text(GRID)
    scenario, spec = load(manifest), ObservationSpec(cameras=("overhead",), image_size=32)
    trained = TrainConfig(steps=4, batch_size=16, shift=2)  # random shifts, which post-training keeps
    model, _ = vision_train.train_vision(vision.collect(scenario, [5], spec), spec, trained)
    vision_train.save_checkpoint(model, spec, tmp_path / "eyes", scenario, trained)
    result = loop(str(manifest), f"vision:{tmp_path / 'eyes'}", str(grid), worst=1, new_episodes=2, post_steps=4,
                  control=True)
    # The untargeted control: the same budget on the manifest as it is, evaluated beside it.
    assert all("untargeted" in r for r in result["table"]) and result["control"]["checkpoint_id"] != result["checkpoint_id"]
    control = vision.VisionPolicy.from_checkpoint(result["control"]["checkpoint"])
    assert control.meta["posttrained_from"] == result["old_checkpoint_id"]
    assert [len(v) for v in control.meta["derived_seeds"].values()] == [2]

    new = vision.VisionPolicy.from_checkpoint(result["checkpoint"])
    assert new.spec == spec and new.meta["posttrained_from"] == result["old_checkpoint_id"]
    assert new.meta["demonstrations"] > 0 and "/vision-policy/" in result["checkpoint"]
    assert new.meta["train"]["shift"] == control.meta["train"]["shift"] == 2
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, rows = wh.query("SELECT attrs->>'model' FROM artifacts WHERE artifact_id = $c", {"c": result["checkpoint_id"]})
        _, edges = wh.query("SELECT DISTINCT relation FROM edges WHERE child_id = $c ORDER BY 1",
                            {"c": result["checkpoint_id"]})
    assert rows == [("vision-policy",)] and edges == [("posttrained_from",), ("trained_on",)]

    # Issue 28, point 4: the failure audit names the failed cells, what was derived from them,
    # the demonstrations simulated there, the post-trained policy and its evaluation.
    audit = CliRunner().invoke(app, ["audit", "failure", "--artifact", result["before_evaluation_id"], "--format", "json"])
    assert audit.exit_code == 0, audit.output
    found = json.loads(audit.output)
    by_kind = {}
    for row in found:
        by_kind.setdefault(row["kind"], set()).add(row["id"])
    (derived,) = result["derived"]
    assert by_kind["then_manifest"] == {derived["manifest_hash"]}
    assert len(by_kind["then_episode"]) == derived["episodes"]
    assert by_kind["then_checkpoint"] == {result["checkpoint_id"]}, [r for r in found if r["kind"] == "then_checkpoint"]
    assert by_kind["then_evaluation"] == {result["after_evaluation_id"]}
    assert "checkpoint" in by_kind and result["old_checkpoint_id"] in by_kind["checkpoint"]
