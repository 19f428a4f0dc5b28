"""The evaluate-rig flow on a tiny tokenizer and world model trained for a few steps here on the
surround rig's tiled video: the tables per horizon, source and pair of views, the check, the
lineage and the CLI (not the figures: these models know nothing)."""

import json

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from flows.cli import app
from flows.rig import evaluate_rig
from models.tokenizer import VideoTokenizer
from models.tokenizer import preset as tokenizer_preset
from models.world_model import WorldModel, post_trainable
from models.world_model import preset as world_preset
from schemas.settings import Settings
from tasks.manifests import dump_yaml, load
from tasks.sim.episode import rollout
from tasks.sim.files import write_episode
from tasks.sim.rigs import tile
from tasks.tokenize import tokens
from tasks.tokenize.train import TrainConfig, train_tokenizer
from tasks.world import checkpoints
from tasks.world.data import CodeSequence, align_actions, encode_frames
from tasks.world.train import WorldTrainConfig, train_world_model
from tests.support import MANIFESTS, lineage_problems
from warehouse.store import Warehouse

SIZE = 128  # four 64 x 64 views, 2 x 2


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    """vehicle_multiview for 4 s (40 frames at 10 fps: 10 latent frames)."""
    manifest = load(MANIFESTS / "vehicle_multiview.yaml").model_copy(update={"horizon_s": 4.0})
    path = tmp_path_factory.mktemp("manifest") / "vehicle_short.yaml"
    path.write_text(dump_yaml(manifest))
    return path, manifest


@pytest.fixture(scope="module")
def models(tmp_path_factory, scenario):
    """A tokenizer trained 5 steps and a world model post-trained 5 steps on the rig's tiled
    video of the manifest's own seed, with its velocity actions."""
    _, manifest = scenario
    folder = tmp_path_factory.mktemp("models")
    ep = rollout(manifest, manifest.seed)
    tiled = tile(ep.frames, manifest.rig("surround").layout)
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    tokenizer = VideoTokenizer(tokenizer_preset("tiny-dv4x8x8"))
    train_tokenizer(tokenizer, [tiled], TrainConfig(steps=5, batch_size=1, clip_frames=5, size=SIZE, crop=32,
                                                    threads=1, log_every=5))
    tok_folder = folder / "tokenizer"
    tokens.save_checkpoint(tokenizer, tok_folder)
    config = world_preset("tiny-wm", max_height=SIZE // 8, max_width=SIZE // 8)
    model = post_trainable(WorldModel(config))
    codes = encode_frames(tokenizer, tiled, SIZE)
    n = 1 + 4 * (codes.shape[0] - 1)
    actions = align_actions(ep.time, ep.action, np.arange(n) / manifest.cameras[0].fps, 4, codes.shape[0],
                            config.action_dim)
    train_world_model(model, [CodeSequence("seed5", codes, "drive", actions)],
                      WorldTrainConfig(steps=5, batch_size=2, threads=1, log_every=5))
    torch.set_num_threads(before)
    trained_on = write_episode(ep, folder, "0" * 64, 0).directory
    wm_folder = folder / "world_model"
    checkpoints.save_checkpoint(model, wm_folder, {"phase": "posttrain", "size": SIZE, "tokenizer": str(tok_folder),
                                                   "episodes": [str(trained_on)], "camera": "surround"})
    return wm_folder, tok_folder


def test_rig_flow_writes_its_tables_check_and_lineage(prefect_harness, data_root, scenario, models):
    path, _ = scenario
    wm_folder, tok_folder = models
    result = evaluate_rig(str(path), str(wm_folder), str(tok_folder), episodes=1, horizon=2)
    assert result["rig"] == "surround" and result["views"] == 4 and result["windows"] >= 2
    folder = data_root / "evaluations" / result["evaluation_id"]
    body = json.loads((folder / "rig.json").read_text())
    sources = ("simulator", "ceiling", "model", "shuffled", "floor")
    assert {(r["horizon"], r["source"]) for r in body["ego"]} == {(h, s) for h in (4, 8) for s in sources}
    by = {(r["horizon"], r["source"]): r for r in body["ego"]}
    for h in (4, 8):
        floor = by[(h, "floor")]  # copy-last shows no motion: its error is the whole motion
        assert floor["ego_mean_cm"] == pytest.approx(floor["true_mean_cm"], abs=0.5) and floor["true_mean_cm"] > 5
        assert by[(h, "simulator")]["ego_mean_cm"] < 0.5 * floor["true_mean_cm"]
        # Against the commanded motion too; the simulator drives it to within a few cm.
        assert floor["command_mean_cm"] > 0.7 * floor["true_mean_cm"]
        assert by[(h, "simulator")]["driven_vs_command_cm"] < 0.2 * floor["true_mean_cm"]
    assert {r["pair"] for r in body["views"]} == {"front-right", "front-left", "right-rear", "left-rear"}
    assert result["checks"] == {"beats_copy_last": body["check"]["passed"]}
    assert "| 8 | floor |" in (folder / "rig.md").read_text() and "from the command" in (folder / "rig.md").read_text()

    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, edges = wh.query("SELECT e.relation, p.kind FROM edges e LEFT JOIN artifacts p "
                            "ON p.artifact_id = e.parent_id WHERE e.child_id = $id ORDER BY 1",
                            {"id": result["evaluation_id"]})
        _, names = wh.query("SELECT name FROM metrics WHERE subject_id = $id", {"id": result["evaluation_id"]})
    assert edges == [("decoded_by", "checkpoint"), ("evaluated", "checkpoint"), ("evaluated_on", "manifest")]
    assert {"rig/model/ego_error_cm/h4", "rig/floor/ego_error_cm/h8", "rig/model/command_error_cm/h4",
            "rig/check/beats_copy_last"} <= \
        {n for (n,) in names}
    assert lineage_problems(Settings().warehouse_path) == {}

    # Again through the CLI: found done, not recomputed.
    cli = CliRunner().invoke(app, ["evaluate", "rig", str(path), "--world-model", str(wm_folder),
                                   "--tokenizer", str(tok_folder), "--episodes", "1", "--horizon", "2"])
    assert cli.exit_code == 0, cli.output
    assert result["evaluation_id"] in cli.output


def test_rig_flow_refuses_a_manifest_without_a_rig_and_a_model_of_another_camera(prefect_harness, data_root,
                                                                              scenario, models, tmp_path):
    path, manifest = scenario
    wm_folder, tok_folder = models
    cli = CliRunner().invoke(app, ["evaluate", "rig", str(MANIFESTS / "camera_control_aisle.yaml"),
                                   "--world-model", str(wm_folder), "--tokenizer", str(tok_folder)])
    assert cli.exit_code == 2 and "no rig" in cli.output, cli.output
    with pytest.raises(ValueError, match="trained this world model"):
        evaluate_rig(str(path), str(wm_folder), str(tok_folder), episodes=1, first_seed=manifest.seed)
    other = tmp_path / "front_model"
    other.mkdir()
    for f in wm_folder.iterdir():
        if f.is_file():
            (other / f.name).write_bytes(f.read_bytes())
    config = json.loads((other / "config.json").read_text())
    (other / "config.json").write_text(json.dumps({**config, "camera": "front"}))
    with pytest.raises(ValueError, match="post-trained on camera 'front', not on rig 'surround'"):
        evaluate_rig(str(path), str(other), str(tok_folder), episodes=1)
