"""The evaluate-camera flow on a tiny tokenizer and world model trained for a few steps here on
the turning camera rig: the table per horizon and source, the check, the lineage and the CLI
(not the figures: these models know nothing)."""

import json

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from flows.camera_control import evaluate_camera
from flows.cli import app
from models.tokenizer import VideoTokenizer
from models.tokenizer import preset as tokenizer_preset
from models.world_model import WorldModel, post_trainable
from models.world_model import preset as world_preset
from schemas.settings import Settings
from tasks.manifests import dump_yaml, load
from tasks.sim.episode import rollout
from tasks.sim.files import write_episode
from tasks.tokenize import tokens
from tasks.tokenize.data import square
from tasks.tokenize.train import TrainConfig, train_tokenizer
from tasks.world import checkpoints
from tasks.world.data import CodeSequence, align_actions, encode_frames
from tasks.world.train import WorldTrainConfig, train_world_model
from tests.support import MANIFESTS, lineage_problems
from warehouse.store import Warehouse

SIZE = 64


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    """camera_control_aisle for 3 s (60 frames at 20 fps: 15 latent frames), into the first turns."""
    manifest = load(MANIFESTS / "camera_control_aisle.yaml").model_copy(update={"horizon_s": 3.0})
    path = tmp_path_factory.mktemp("manifest") / "camera_control_short.yaml"
    path.write_text(dump_yaml(manifest))
    return path, manifest


@pytest.fixture(scope="module")
def models(tmp_path_factory, scenario):
    """A tokenizer trained 5 steps and a world model post-trained 5 steps on the front camera of
    the manifest's own seed, with its twist actions."""
    _, manifest = scenario
    folder = tmp_path_factory.mktemp("models")
    ep = rollout(manifest, manifest.seed)
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    tokenizer = VideoTokenizer(tokenizer_preset("tiny-dv4x8x8"))
    train_tokenizer(tokenizer, [square(ep.frames["front"], SIZE)],
                    TrainConfig(steps=5, batch_size=1, clip_frames=5, size=SIZE, crop=32, threads=1, log_every=5))
    tok_folder = folder / "tokenizer"
    tokens.save_checkpoint(tokenizer, tok_folder)
    config = world_preset("tiny-wm", max_height=SIZE // 8, max_width=SIZE // 8)
    model = post_trainable(WorldModel(config))
    codes = encode_frames(tokenizer, ep.frames["front"], SIZE)
    n = 1 + 4 * (codes.shape[0] - 1)
    assert ep.action.shape[1] == 3  # [vx, vy, wz]
    actions = align_actions(ep.time, ep.action, np.arange(n) / manifest.cameras[0].fps, 4, codes.shape[0],
                            config.action_dim)
    train_world_model(model, [CodeSequence("seed7", codes, "drive", actions)],
                      WorldTrainConfig(steps=5, batch_size=2, threads=1, log_every=5))
    torch.set_num_threads(before)
    trained_on = write_episode(ep, folder, "0" * 64, 0).directory
    wm_folder = folder / "world_model"
    checkpoints.save_checkpoint(model, wm_folder, {"phase": "posttrain", "size": SIZE, "tokenizer": str(tok_folder),
                                                   "episodes": [str(trained_on)]})
    return wm_folder, tok_folder


def test_camera_flow_writes_its_table_check_and_lineage(prefect_harness, data_root, scenario, models):
    path, _ = scenario
    wm_folder, tok_folder = models
    result = evaluate_camera(str(path), str(wm_folder), str(tok_folder), episodes=1, horizon=2)
    assert result["windows"] == 4 and result["camera"] == "front" and result["context"] == 6
    folder = data_root / "evaluations" / result["evaluation_id"]
    body = json.loads((folder / "camera.json").read_text())
    table = body["table"]
    assert {(r["horizon"], r["source"]) for r in table} == {(h, s) for h in (4, 8)
                                                           for s in ("simulator", "ceiling", "model", "shuffled",
                                                                     "floor")}
    by = {(r["horizon"], r["source"]): r for r in table}
    for h in (4, 8):
        # Copy-last shows no motion: its rotation error is the true rotation, its direction a 90.
        floor = by[(h, "floor")]
        assert floor["rotation_mean_deg"] == pytest.approx(floor["true_rotation_mean_deg"])
        assert floor["direction_mean_deg"] in (90.0, None)
        # The rig turns through the slalom, and the estimator reads it from the true frames.
        assert floor["true_rotation_mean_deg"] > 2
        assert by[(h, "simulator")]["rotation_mean_deg"] < 0.5 * floor["true_rotation_mean_deg"]
    assert set(body["check"]) >= {"passed", "model_vs_floor_deg"}
    assert result["checks"] == {"beats_copy_last": body["check"]["passed"]}
    assert "| 8 | floor |" in (folder / "camera.md").read_text()

    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, edges = wh.query("SELECT e.relation, p.kind FROM edges e LEFT JOIN artifacts p "
                            "ON p.artifact_id = e.parent_id WHERE e.child_id = $id ORDER BY 1",
                            {"id": result["evaluation_id"]})
        _, names = wh.query("SELECT name FROM metrics WHERE subject_id = $id", {"id": result["evaluation_id"]})
    assert edges == [("decoded_by", "checkpoint"), ("evaluated", "checkpoint"), ("evaluated_on", "manifest")]
    assert {"camera/model/rotation_error_deg/h4", "camera/floor/rotation_error_deg/h8",
            "camera/check/beats_copy_last"} <= {n for (n,) in names}
    assert lineage_problems(Settings().warehouse_path) == {}

    # Again through the CLI: found done, not recomputed.
    cli = CliRunner().invoke(app, ["evaluate", "camera", str(path), "--world-model", str(wm_folder),
                                   "--tokenizer", str(tok_folder), "--episodes", "1", "--horizon", "2"])
    assert cli.exit_code == 0, cli.output
    assert result["evaluation_id"] in cli.output


def test_camera_flow_refuses_a_rig_without_moving_cameras_and_trained_seeds(prefect_harness, data_root, scenario,
                                                                           models):
    path, manifest = scenario
    wm_folder, tok_folder = models
    with pytest.raises(ValueError, match="trained this world model"):
        evaluate_camera(str(path), str(wm_folder), str(tok_folder), episodes=1, first_seed=manifest.seed)
    cli = CliRunner().invoke(app, ["evaluate", "camera", str(MANIFESTS / "conveyor_push.yaml"),
                                   "--world-model", str(wm_folder), "--tokenizer", str(tok_folder)])
    assert cli.exit_code == 2 and "no camera rides on the base" in cli.output, cli.output


@pytest.fixture(scope="module")
def diffusion_models(tmp_path_factory, scenario):
    """A continuous tokenizer trained 5 steps and a diffusion world model post-trained 5 steps on
    the front camera's latents and twist actions, saved as flows/train.py saves them."""
    from models.diffusion_world import post_trainable as diffusion_trainable
    from models.diffusion_world import preset as diffusion_preset
    from tasks.world import diffusion

    _, manifest = scenario
    folder = tmp_path_factory.mktemp("diffusion")
    ep = rollout(manifest, manifest.seed)
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    tokenizer = VideoTokenizer(tokenizer_preset("tiny-cv4x8x8"))
    train_tokenizer(tokenizer, [square(ep.frames["front"], SIZE)],
                    TrainConfig(steps=5, batch_size=1, clip_frames=5, size=SIZE, crop=32, threads=1, log_every=5))
    tok_folder = folder / "tokenizer"
    tokens.save_checkpoint(tokenizer, tok_folder)
    config = diffusion_preset("tiny-dwm", latent_channels=tokenizer.config.latent_channels, max_height=SIZE // 8,
                              max_width=SIZE // 8)
    model = diffusion_trainable(diffusion.DiffusionWorldModel(config))
    latents = diffusion.encode_latents(tokenizer, ep.frames["front"], SIZE)
    n = 1 + 4 * (latents.shape[0] - 1)
    actions = align_actions(ep.time, ep.action, np.arange(n) / manifest.cameras[0].fps, 4, latents.shape[0],
                            config.action_dim)
    diffusion.train_diffusion(model, [diffusion.LatentSequence("seed7", latents, "drive", actions)],
                              diffusion.DiffusionTrainConfig(steps=5, batch_size=2, threads=1, log_every=5))
    torch.set_num_threads(before)
    trained_on = write_episode(ep, folder, "0" * 64, 0).directory
    wm_folder = folder / "world_model"
    diffusion.save_checkpoint(model, wm_folder, {"phase": "posttrain", "size": SIZE, "tokenizer": str(tok_folder),
                                                 "episodes": [str(trained_on)]})
    return wm_folder, tok_folder


def test_camera_flow_evaluates_a_diffusion_world_model(prefect_harness, data_root, scenario, diffusion_models):
    """Either family: the diffusion model samples with --sampler-steps, the same table comes out."""
    path, _ = scenario
    wm_folder, tok_folder = diffusion_models
    result = evaluate_camera(str(path), str(wm_folder), str(tok_folder), episodes=1, horizon=2, sampler_steps=2)
    assert result["windows"] == 4 and result["rollout_s_per_frame"] > 0
    body = json.loads((data_root / "evaluations" / result["evaluation_id"] / "camera.json").read_text())
    assert body["params"]["sampler_steps"] == 2
    assert {r["source"] for r in body["table"]} == {"simulator", "ceiling", "model", "shuffled", "floor"}
