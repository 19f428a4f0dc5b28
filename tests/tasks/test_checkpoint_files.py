"""Checkpoint folders read back with one-line errors naming the file (a world model as the example)."""

import json

import pytest
import torch

from models.world_model import WorldModel, preset
from tasks.checkpoint_files import CONFIG_FILE, WEIGHTS_FILE, CheckpointError
from tasks.world.checkpoints import load_checkpoint, save_checkpoint


@pytest.fixture
def folder(tmp_path):
    torch.manual_seed(0)
    model = WorldModel(preset("tiny-wm"))
    save_checkpoint(model, tmp_path / "wm", {"size": 64})
    return tmp_path / "wm"


def test_round_trip(folder):
    torch.manual_seed(0)
    saved = WorldModel(preset("tiny-wm"))
    loaded = load_checkpoint(folder)
    assert not loaded.training
    assert all(torch.equal(a, b) for a, b in zip(loaded.state_dict().values(), saved.state_dict().values()))


@pytest.mark.parametrize("damage, problem", [
    (lambda f: (f / CONFIG_FILE).unlink(), "not a world-model checkpoint folder \\(no config.json\\)"),
    (lambda f: (f / CONFIG_FILE).write_text("{not json"), "config.json: unreadable"),
    (lambda f: (f / CONFIG_FILE).write_text("[]"), "config.json: not a world-model checkpoint config"),
    (lambda f: (f / WEIGHTS_FILE).unlink(), "no model.safetensors"),
    (lambda f: (f / WEIGHTS_FILE).write_bytes(b"\xff" * 64), "model.safetensors: unreadable weights"),
])
def test_a_damaged_checkpoint_names_the_file_and_the_problem(folder, damage, problem):
    damage(folder)
    with pytest.raises(CheckpointError, match=problem):
        load_checkpoint(folder)


def test_weights_of_another_architecture_or_a_bad_config_field(folder):
    body = json.loads((folder / CONFIG_FILE).read_text())
    (folder / CONFIG_FILE).write_text(json.dumps({**body, "world_model": {**body["world_model"], "width": 32}}))
    with pytest.raises(CheckpointError, match="model.safetensors: the weights do not fit the architecture"):
        load_checkpoint(folder)
    (folder / CONFIG_FILE).write_text(json.dumps({**body, "world_model": {**body["world_model"], "layers": -1}}))
    with pytest.raises(CheckpointError, match="config.json: world_model: layers: Input should be greater"):
        load_checkpoint(folder)
