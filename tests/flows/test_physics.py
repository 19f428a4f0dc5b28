"""The evaluate-physics flow on a tiny tokenizer and world model trained for a few steps here:
the table, the plots and the lineage rows (not the figures: these models know nothing)."""

import json

import numpy as np
import pytest
import torch
from PIL import Image
from typer.testing import CliRunner

from flows.cli import app
from flows.physics import evaluate_physics
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
    """conveyor_push for 2.5 s, with a second overhead camera 20 cm beside the first (so the
    flow also runs its two-view check)."""
    base = load(MANIFESTS / "conveyor_push.yaml")
    second = base.cameras[0].model_copy(update={"name": "overhead_b", "position": (0.45, 0.2, 1.4)})
    manifest = base.model_copy(update={"horizon_s": 2.5, "cameras": (base.cameras[0], second)})
    path = tmp_path_factory.mktemp("manifest") / "push_two_cameras.yaml"
    path.write_text(dump_yaml(manifest))
    return path, manifest


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """One torch thread: on a shared two-core machine, two threads waiting on each other made
    each training step 10 to 50 times slower (measured here under load 7)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def models(tmp_path_factory, scenario):
    """A tokenizer trained 5 steps (on 32 px crops) and a world model post-trained 5 steps on
    seed 11's episode: enough to exercise every path, far too little to predict anything."""
    _, manifest = scenario
    folder = tmp_path_factory.mktemp("models")
    ep = rollout(manifest, manifest.seed)
    frames = square(ep.frames["overhead"], SIZE)
    torch.manual_seed(0)
    tokenizer = VideoTokenizer(tokenizer_preset("tiny-dv4x8x8"))
    train_tokenizer(tokenizer, [frames], TrainConfig(steps=5, batch_size=1, clip_frames=5, size=SIZE, crop=32,
                                                     threads=1, log_every=5))
    tok_folder = folder / "tokenizer"
    tokens.save_checkpoint(tokenizer, tok_folder)

    config = world_preset("tiny-wm", max_height=SIZE // 8, max_width=SIZE // 8)
    model = post_trainable(WorldModel(config))
    codes = encode_frames(tokenizer, ep.frames["overhead"], SIZE)
    n = 1 + 4 * (codes.shape[0] - 1)
    actions = align_actions(ep.time, ep.action, np.arange(n) / 30.0, 4, codes.shape[0], config.action_dim)
    train_world_model(model, [CodeSequence("seed11", codes, "push", actions)],
                      WorldTrainConfig(steps=5, batch_size=2, threads=1, log_every=5))
    trained_on = write_episode(ep, folder, "0" * 64, 0).directory  # videos, steps and meta.json, as simulate writes
    wm_folder = folder / "world_model"
    checkpoints.save_checkpoint(model, wm_folder, {"phase": "posttrain", "size": SIZE, "tokenizer": str(tok_folder),
                                                   "episodes": [str(trained_on)]})
    return wm_folder, tok_folder


def test_physics_flow_writes_table_plots_and_lineage(prefect_harness, data_root, scenario, models):
    path, manifest = scenario
    wm_folder, tok_folder = models
    result = evaluate_physics(str(path), str(wm_folder), str(tok_folder), episodes=1, horizon=2)
    assert result["episodes"] == 1 and result["context"] == 6 and result["windows"] == 6  # 19 latent frames, stride 2
    assert result["rollout_s_per_frame"] > 0  # the cost of a generated frame, beside the figures
    folder = data_root / "evaluations" / result["evaluation_id"]
    body = json.loads((folder / "physics.json").read_text())
    rows = body["rows"]
    assert {(r["horizon"], r["method"]) for r in rows} == {(h, m) for h in range(1, 9)
                                                          for m in ("model", "shuffled", "floor", "ceiling")}
    assert all(r["windows"] == 6 and r["psnr"] > 5 and -1 <= r["ssim"] <= 1 for r in rows)
    assert {r["source"] for r in body["sampson"]} == {"simulator", "ceiling", "model"}
    assert {r["pair"] for r in body["sampson"]} == {"overhead-overhead_b"}
    assert set(body["checks"]) == {"beats_floor", "actions_matter", "psnr_between_floor_and_ceiling"}
    for name in ("error_vs_horizon", "strip"):
        with Image.open(folder / f"{name}.png") as image:
            assert image.size[0] > 200 and image.size[1] > 100
    report = (folder / "physics.md").read_text()
    assert "### package position" in report and "| held out | 6 |" in report and "| trained | 6 |" in report
    fitted = body["teacher_forced"]  # one episode each side, 19 latent frames: windows of 8 at 0, 2, ..., 10
    assert set(fitted) == {"held_out", "trained"} and all(f["windows"] == 6 and f["loss"] > 0 for f in fitted.values())

    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, evaluation = wh.query("SELECT artifact_id, uri FROM artifacts WHERE kind = 'evaluation'")
        _, edges = wh.query("SELECT e.relation, p.kind FROM edges e LEFT JOIN artifacts p "
                            "ON p.artifact_id = e.parent_id WHERE e.child_id = $id ORDER BY 1",
                            {"id": result["evaluation_id"]})
        _, plots = wh.query("SELECT a.attrs->>'plot' FROM edges e JOIN artifacts a ON a.artifact_id = e.child_id "
                            "WHERE e.parent_id = $id AND e.relation = 'plotted' ORDER BY 1",
                            {"id": result["evaluation_id"]})
        _, names = wh.query("SELECT name FROM metrics WHERE subject_id = $id", {"id": result["evaluation_id"]})
        _, runs = wh.query("SELECT status FROM runs WHERE flow = 'evaluate-physics'")
    assert evaluation == [(result["evaluation_id"], f"evaluations/{result['evaluation_id']}/physics.json")]
    assert [(r, k) for r, k in edges] == [("decoded_by", "checkpoint"), ("evaluated", "checkpoint"),
                                          ("evaluated_on", "manifest")]
    assert [p for (p,) in plots] == ["error_vs_horizon", "strip"]
    names = {n for (n,) in names}
    assert {"physics/psnr/h4", "physics/ssim/h8", "physics/floor/psnr/h4", "physics/ceiling/ssim/h8",
            "physics/shuffled/psnr/h8", "physics/check/beats_floor", "physics/teacher_forced/trained/loss",
            "physics/teacher_forced/held_out/changed_accuracy",
            "physics/simulator/sampson_median_px/overhead-overhead_b/h4"} <= names
    assert not any(n.endswith(("/h1", "/h2", "/h3")) for n in names)  # every 4 frames (a latent step)
    assert runs == [("completed",)]
    assert lineage_problems(Settings().warehouse_path) == {}

    # The same evaluation again (here through the CLI) is found done and not recomputed.
    cli = CliRunner().invoke(app, ["evaluate", "physics", str(path), "--world-model", str(wm_folder),
                                   "--tokenizer", str(tok_folder), "--episodes", "1", "--horizon", "2"])
    assert cli.exit_code == 0, cli.output
    assert result["evaluation_id"] in cli.output
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, n = wh.query("SELECT count(*) FROM stage_runs WHERE stage = 'evaluate_physics'")
    assert n == [(1,)]


def test_physics_refuses_seeds_the_model_trained_on(prefect_harness, data_root, scenario, models):
    path, manifest = scenario
    wm_folder, tok_folder = models
    with pytest.raises(ValueError, match="trained this world model"):
        evaluate_physics(str(path), str(wm_folder), str(tok_folder), episodes=1, first_seed=manifest.seed)
    cli = CliRunner().invoke(app, ["evaluate", "physics", str(path), "--world-model", str(data_root / "nowhere")])
    assert cli.exit_code == 2 and "not a checkpoint id" in cli.output


@pytest.fixture(scope="module")
def diffusion_models(tmp_path_factory, scenario):
    """A continuous tokenizer trained 5 steps and a diffusion world model post-trained 5 steps on
    seed 11's latents, saved as flows/train.py saves them (config key diffusion_world_model)."""
    from models.diffusion_world import post_trainable as diffusion_trainable
    from models.diffusion_world import preset as diffusion_preset
    from tasks.world import diffusion

    _, manifest = scenario
    folder = tmp_path_factory.mktemp("diffusion")
    ep = rollout(manifest, manifest.seed)
    torch.manual_seed(0)
    tokenizer = VideoTokenizer(tokenizer_preset("tiny-cv4x8x8"))
    train_tokenizer(tokenizer, [square(ep.frames["overhead"], SIZE)],
                    TrainConfig(steps=5, batch_size=1, clip_frames=5, size=SIZE, crop=32, threads=1, log_every=5))
    tok_folder = folder / "tokenizer"
    tokens.save_checkpoint(tokenizer, tok_folder)
    config = diffusion_preset("tiny-dwm", latent_channels=tokenizer.config.latent_channels, max_height=SIZE // 8,
                              max_width=SIZE // 8)
    model = diffusion_trainable(diffusion.DiffusionWorldModel(config))
    latents = diffusion.encode_latents(tokenizer, ep.frames["overhead"], SIZE)
    n = 1 + 4 * (latents.shape[0] - 1)
    actions = align_actions(ep.time, ep.action, np.arange(n) / 30.0, 4, latents.shape[0], config.action_dim)
    diffusion.train_diffusion(model, [diffusion.LatentSequence("seed11", latents, "push", actions)],
                              diffusion.DiffusionTrainConfig(steps=5, batch_size=2, threads=1, log_every=5))
    trained_on = write_episode(ep, folder, "0" * 64, 0).directory
    wm_folder = folder / "world_model"
    diffusion.save_checkpoint(model, wm_folder, {"phase": "posttrain", "size": SIZE, "tokenizer": str(tok_folder),
                                                 "episodes": [str(trained_on)]})
    return wm_folder, tok_folder


def test_physics_flow_evaluates_a_diffusion_world_model(prefect_harness, data_root, scenario, diffusion_models, models):
    """The same table, checks and lineage for the diffusion family (sampled with --sampler-steps
    Euler steps; no teacher-forced scores, an autoregressive quantity), and a tokenizer of the
    other variant named in one line."""
    path, _ = scenario
    wm_folder, tok_folder = diffusion_models
    result = evaluate_physics(str(path), str(wm_folder), str(tok_folder), episodes=1, horizon=2, sampler_steps=2)
    assert result["episodes"] == 1 and result["context"] == 6 and result["windows"] == 6
    assert result["rollout_s_per_frame"] > 0
    folder = data_root / "evaluations" / result["evaluation_id"]
    body = json.loads((folder / "physics.json").read_text())
    assert {(r["horizon"], r["method"]) for r in body["rows"]} == {(h, m) for h in range(1, 9)
                                                                  for m in ("model", "shuffled", "floor", "ceiling")}
    assert all(r["windows"] == 6 and r["psnr"] > 5 for r in body["rows"])
    assert body["params"]["sampler_steps"] == 2 and body["teacher_forced"] == {}
    assert {r["pair"] for r in body["sampson"]} == {"overhead-overhead_b"}
    assert (folder / "physics.md").is_file() and (folder / "strip.png").is_file()
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, edges = wh.query("SELECT e.relation, p.kind FROM edges e LEFT JOIN artifacts p "
                            "ON p.artifact_id = e.parent_id WHERE e.child_id = $id ORDER BY 1",
                            {"id": result["evaluation_id"]})
    assert [(r, k) for r, k in edges] == [("decoded_by", "checkpoint"), ("evaluated", "checkpoint"),
                                          ("evaluated_on", "manifest")]
    assert lineage_problems(Settings().warehouse_path) == {}

    cli = CliRunner().invoke(app, ["evaluate", "physics", str(path), "--world-model", str(wm_folder), "--tokenizer",
                                   str(tok_folder), "--episodes", "1", "--horizon", "2", "--sampler-steps", "2"])
    assert cli.exit_code == 0 and result["evaluation_id"] in cli.output, cli.output  # done before
    _, ar_tokenizer = models
    wrong = CliRunner().invoke(app, ["evaluate", "physics", str(path), "--world-model", str(wm_folder),
                                     "--tokenizer", str(ar_tokenizer)], terminal_width=400)
    assert wrong.exit_code == 2 and "a discrete tokenizer; a continuous one is needed here" in wrong.output
