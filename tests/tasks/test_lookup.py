"""Checkpoints named by folder or by id prefix, looked up in lineage."""

import json

import pytest

from tasks.lookup import checkpoint_by_id, policy_spec, world_model_folder
from schemas.records import ArtifactRecord, LineageBatch
from tasks.checkpoint_files import CONFIG_FILE, CheckpointError
from warehouse.store import Warehouse

WM_A, WM_B, BC = "a1b2c3d4e5f6" + "0" * 12, "a1b2c3d4e5f6" + "1" * 12, "bcbcbcbcbcbc" + "2" * 12


def _checkpoint(root, warehouse, artifact_id, attrs, config):
    folder = root / "checkpoints" / attrs["model"] / artifact_id
    folder.mkdir(parents=True)
    (folder / CONFIG_FILE).write_text(json.dumps(config))
    warehouse.write(LineageBatch(artifacts=[ArtifactRecord(
        artifact_id=artifact_id, kind="checkpoint", uri=f"checkpoints/{attrs['model']}/{artifact_id}/model.safetensors",
        sha256=artifact_id, attrs=attrs)]))
    return folder


@pytest.fixture
def lineage(tmp_path):
    with Warehouse(tmp_path / "lineage.duckdb") as warehouse:
        config = {"world_model": {}, "tokenizer": "checkpoints/tok", "size": 64}
        folders = {
            WM_A: _checkpoint(tmp_path, warehouse, WM_A, {"model": "world_model", "phase": "posttrain"}, config),
            WM_B: _checkpoint(tmp_path, warehouse, WM_B, {"model": "world_model", "phase": "posttrain"},
                              {"world_model": {}}),
            BC: _checkpoint(tmp_path, warehouse, BC, {"model": "bc-policy"}, {"bc": {}}),
        }
        yield warehouse, tmp_path, folders


def test_an_id_prefix_names_one_checkpoint(lineage):
    warehouse, root, folders = lineage
    condition = "attrs->>'model' = 'world_model'"
    assert checkpoint_by_id(warehouse, WM_A[:14], condition, "world model")[0] == WM_A
    with pytest.raises(FileNotFoundError, match="world model a1b2c3d4e5f6: more than one world model checkpoint"):
        checkpoint_by_id(warehouse, WM_A[:12], condition, "world model")
    with pytest.raises(FileNotFoundError, match="no world model checkpoint with that id"):
        checkpoint_by_id(warehouse, BC, condition, "world model")  # a policy is not a world model
    with pytest.raises(FileNotFoundError, match="no lineage warehouse yet"):
        checkpoint_by_id(None, WM_A, condition, "world model")


def test_world_model_by_folder_id_or_newest(lineage, tmp_path):
    warehouse, root, folders = lineage
    assert world_model_folder(warehouse, root, WM_A[:13]) == folders[WM_A]
    assert world_model_folder(None, root, str(folders[WM_A])) == folders[WM_A]  # a folder needs no lineage
    with pytest.raises(CheckpointError, match=f"{WM_B}/config.json: not a post-trained world model's config "
                                                r"\(no tokenizer, size\)"):
        world_model_folder(warehouse, root, WM_B)
    with pytest.raises(FileNotFoundError, match="not-a-folder: no such checkpoint folder, and not a checkpoint id"):
        world_model_folder(warehouse, root, "not-a-folder")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(FileNotFoundError, match="empty: not a world model checkpoint folder"):
        world_model_folder(warehouse, root, str(empty))
    (empty / CONFIG_FILE).write_text("[]")
    with pytest.raises(CheckpointError, match="not a world-model checkpoint config"):
        world_model_folder(warehouse, root, str(empty))
    with pytest.raises(FileNotFoundError, match="no post-trained world model in lineage"):
        world_model_folder(None, root, None)
    # The newest post-trained one; WM_B (recorded last) lacks its tokenizer, and says so.
    with pytest.raises(CheckpointError, match=f"{WM_B}/config.json"):
        world_model_folder(warehouse, root, None)


def test_a_policy_id_becomes_its_folder(lineage):
    warehouse, root, folders = lineage
    assert policy_spec(warehouse, root, f"bc:{BC[:12]}") == f"bc:{folders[BC]}"
    for unchanged in ("scripted", "scripted:0.8", "bc:/no/such/folder", f"bc:{folders[BC]}", "bc:"):
        assert policy_spec(warehouse, root, unchanged) == unchanged
    with pytest.raises(FileNotFoundError, match="no behaviour-cloning policy checkpoint with that id"):
        policy_spec(warehouse, root, f"bc:{WM_A}")
