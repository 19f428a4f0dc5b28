"""The train flow end to end: simulate -> curate -> tokenize -> pre-train on tokens -> post-train on episodes."""

import re
from pathlib import Path

from typer.testing import CliRunner

from flows.cli import app
from flows.curate import curate
from flows.simulate import simulate
from flows.tokenize import tokenize
from flows.train import train
from models.world_model import WorldModel
from schemas.settings import Settings
from tasks.world import checkpoints
from tests.support import MANIFESTS, lineage_problems
from warehouse import audit
from warehouse.store import Warehouse

runner = CliRunner()


def _small_manifest(tmp_path: Path) -> Path:
    """conveyor_push at 64 x 64 for 3 s: long enough for a 2 s curated scene."""
    text = (MANIFESTS / "conveyor_push.yaml").read_text()
    path = tmp_path / "small.yaml"
    path.write_text(text.replace("horizon_s: 5.0", "horizon_s: 3.0").replace("[128, 128]", "[64, 64]"))
    return path


def test_train_pretrains_posttrains_records_lineage_and_skips_on_rerun(prefect_harness, data_root, tmp_path):
    manifest = _small_manifest(tmp_path)
    mh = simulate(str(manifest), 2)["manifest_hash"]
    config = tmp_path / "curate.yaml"
    config.write_text("overlay_text: {action: tag}\n")
    curated = curate([str(data_root / "episodes")], str(manifest), str(config))
    assert curated["clips"] >= 1
    tok = tokenize(mh, "tiny-dv4x8x8", steps=2, size=32, batch_size=2)

    result = train(str(manifest), pretrain_steps=3, posttrain_steps=3)
    assert result["pretrained"] and result["posttrained"] and result["tokenizer_id"] == tok["checkpoint_id"]
    assert result["episodes"] == 2 and result["episode_videos"] == 2 and result["sequences"] == curated["clips"]
    for phase in ("pretrain", "posttrain"):
        folder = Path(result[f"{phase}_checkpoint"])
        assert (folder / "model.safetensors").is_file() and list((folder / "tensorboard").glob("events.out.tfevents.*"))
        model = checkpoints.load_checkpoint(folder)
        assert isinstance(model, WorldModel) and model.config.action_conditioned == (phase == "posttrain")
        assert model.config.codebook_size == 1000 and (model.config.max_height, model.config.max_width) == (4, 4)
        assert checkpoints.read_config(folder)["phase"] == phase
    assert list((data_root / "cache" / "episode_codes").rglob("*.npz"))

    pre, post = result["pretrain_checkpoint_id"], result["posttrain_checkpoint_id"]
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, ckpts = wh.query("SELECT artifact_id, attrs->>'phase', manifest_hash FROM artifacts WHERE kind = 'checkpoint' "
                            "AND attrs->>'model' = 'world_model' ORDER BY 2")
        _, edges = wh.query("SELECT e.child_id, e.relation, p.kind, count(*) FROM edges e "
                            "JOIN artifacts p ON p.artifact_id = e.parent_id WHERE e.child_id IN ($pre, $post) "
                            "GROUP BY ALL ORDER BY 1, 2, 3", {"pre": pre, "post": post})
        _, n_tokens = wh.query("SELECT count(*) FROM artifacts WHERE kind = 'token_shard'")
        _, metrics = wh.query("SELECT subject_id, name, step FROM metrics WHERE subject_id IN ($pre, $post) ORDER BY 1, 2",
                              {"pre": pre, "post": post})
        _, stages = wh.query("SELECT stage, count(*) FROM stage_runs WHERE stage LIKE '%world_model' GROUP BY 1 ORDER BY 1")
        sql, _ = audit.bind("ancestry", {"artifact": "x"})
        _, ancestry = wh.query(sql, {"artifact": post})
    assert [(i, p) for i, p, _ in ckpts] == [(post, "posttrain"), (pre, "pretrain")] and ckpts[0][2] == mh
    tokens = n_tokens[0][0]
    assert sorted((c == post, rel, kind, n) for c, rel, kind, n in edges) == sorted([
        (False, "trained_on", "checkpoint", 1), (False, "trained_on", "token_shard", tokens),
        (True, "posttrained_from", "checkpoint", 1), (True, "trained_on", "checkpoint", 1),
        (True, "trained_on", "episode", 2)])
    assert sorted(metrics) == sorted((c, f"train_{m}", 3) for c in (pre, post) for m in ("accuracy", "loss"))
    assert stages == [("posttrain_world_model", 1), ("pretrain_world_model", 1)]
    assert {r[1] for r in ancestry} >= {"checkpoint", "episode", "token_shard", "shard", "clip", "manifest"}
    assert lineage_problems(Settings().warehouse_path) == {}

    # A policy evaluated in this world model traces back through it: the failure audit lists the
    # checkpoints, their token shards, the curated shards and clips, the episode videos and manifests.
    from flows.evaluate import evaluate

    grid = tmp_path / "grid.yaml"
    grid.write_text("name: one\ncells: [{name: nominal}]\nepisodes: 1\n")
    done = evaluate(str(manifest), str(grid), policies=["scripted"], world_model=result["posttrain_checkpoint"],
                    detector=False)
    evaluation_id = done["evaluations"][0]["evaluation_id"]
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, rows = wh.query(*audit.bind("failure", {"artifact": evaluation_id}))
    kinds = {r[1] for r in rows}
    assert {"panel", "checkpoint", "token_shard", "shard", "clip", "episode_video", "episode", "manifest"} <= kinds
    assert {post, pre, tok["checkpoint_id"]} <= {r[2] for r in rows if r[1] == "checkpoint"}

    again = runner.invoke(app, ["train", str(manifest), "--steps", "3", "--post-steps", "3"])
    assert again.exit_code == 0, again.output
    assert f"pre-trained {pre} (already trained), post-trained {post} (already trained)" in " ".join(again.output.split())
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, runs = wh.query("SELECT status FROM runs WHERE flow = 'train'")
    assert runs == [("completed",), ("completed",)]
    camera = runner.invoke(app, ["train", str(manifest), "--camera", "nope"])  # refused before pre-training
    assert camera.exit_code == 2 and "--camera 'nope': the episodes of" in camera.output

    # --action-totals is a post-training option: the pre-trained checkpoint is reused, a new
    # post-trained one records the layout its actions were aligned with.
    totals = runner.invoke(app, ["train", str(manifest), "--steps", "3", "--post-steps", "3", "--action-totals", "3"])
    assert totals.exit_code == 0, totals.output
    said = " ".join(totals.output.split())
    new_post = re.search(r"post-trained (\w+) \(trained\)", said).group(1)
    assert f"pre-trained {pre} (already trained)" in said and new_post != post
    folder = next((data_root / "checkpoints").rglob(new_post))
    assert checkpoints.load_checkpoint(folder).config.action_totals == 3
    assert checkpoints.load_checkpoint(Path(result["posttrain_checkpoint"])).config.action_totals == 0
    wide = runner.invoke(app, ["train", str(manifest), "--action-totals", "4"])  # 5 values + 4 > 8
    assert wide.exit_code == 2 and "--action-totals 4: the episodes of" in " ".join(wide.output.split())

    # --also: a second manifest's episodes join post-training (a new post-trained checkpoint on
    # both sets of episodes, with lineage edges to all of them); the pre-trained one is reused.
    other = tmp_path / "other.yaml"
    other.write_text(manifest.read_text().replace("\nseed: 11", "\nseed: 111"))
    other_mh = simulate(str(other), 1)["manifest_hash"]
    both = runner.invoke(app, ["train", str(manifest), "--also", str(other), "--steps", "3", "--post-steps", "3"])
    assert both.exit_code == 0, both.output
    said = " ".join(both.output.split())
    assert f"pre-trained {pre} (already trained)" in said and "on 3 episodes" in said
    both_post = re.search(r"post-trained (\w+) \(trained\)", said).group(1)
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, rows = wh.query("SELECT a.manifest_hash, count(*) FROM edges e "
                           "JOIN artifacts a ON a.artifact_id = e.parent_id "
                           "WHERE e.child_id = $c AND a.kind = 'episode' GROUP BY 1 ORDER BY 2", {"c": both_post})
    assert sorted(rows) == sorted([(mh, 2), (other_mh, 1)])
    missing = runner.invoke(app, ["train", str(manifest), "--also", "0" * 64])
    assert missing.exit_code == 3 and "no simulated episodes" in missing.output  # not built


def test_cli_refuses_bad_train_arguments(data_root, tmp_path):
    bad = runner.invoke(app, ["train", str(MANIFESTS / "conveyor_push.yaml"), "--preset", "huge"])
    assert bad.exit_code == 2 and "unknown world model preset" in bad.output
    none = runner.invoke(app, ["train", str(MANIFESTS / "conveyor_push.yaml")])
    assert none.exit_code == 3 and "no simulated episodes" in none.output  # not built
    missing = runner.invoke(app, ["train", str(tmp_path / "nothing.yaml")])
    assert missing.exit_code == 2
    garbage = tmp_path / "tok"
    garbage.mkdir()
    (garbage / "config.json").write_text("{}")
    for name, problem in ((str(garbage), "config.json: not a tokenizer checkpoint config"),
                          ("0123456789abcdef", "no lineage warehouse yet")):
        for args in (["train", str(MANIFESTS / "conveyor_push.yaml"), "--tokenizer", name],
                     ["tokenize", str(tmp_path), "--init", name]):
            result = runner.invoke(app, args)
            assert result.exit_code == 2 and problem in result.output, (args, result.output)


def test_train_diffusion_on_a_continuous_tokenizer_records_lineage_and_skips_on_rerun(prefect_harness, data_root,
                                                                                      tmp_path):
    """--family diffusion: the continuous tokenizer's latent shards pre-train the diffusion world
    model, the episodes (encoded to latents, cached beside the codes cache) post-train it; the
    checkpoints, edges and curves land in lineage as the autoregressive model's do (loss only),
    a re-run skips both, and a policy evaluation judges frames it generates."""
    from models.diffusion_world import DiffusionWorldModel
    from tasks.world import diffusion

    manifest = _small_manifest(tmp_path)
    mh = simulate(str(manifest), 2)["manifest_hash"]
    config = tmp_path / "curate.yaml"
    config.write_text("overlay_text: {action: tag}\n")
    curated = curate([str(data_root / "episodes")], str(manifest), str(config))
    tok = tokenize(mh, "tiny-cv4x8x8", steps=2, size=32, batch_size=2)

    result = train(str(manifest), preset_name="tiny-dwm", family="diffusion", pretrain_steps=3, posttrain_steps=3)
    assert result["pretrained"] and result["posttrained"] and result["tokenizer_id"] == tok["checkpoint_id"]
    assert result["episodes"] == 2 and result["episode_videos"] == 2 and result["sequences"] == curated["clips"]
    for phase in ("pretrain", "posttrain"):
        folder = Path(result[f"{phase}_checkpoint"])
        assert (folder / "model.safetensors").is_file() and list((folder / "tensorboard").glob("events.out.tfevents.*"))
        model = diffusion.load_checkpoint(folder)
        assert isinstance(model, DiffusionWorldModel) and model.config.action_conditioned == (phase == "posttrain")
        assert model.config.latent_channels == 16 and (model.config.max_height, model.config.max_width) == (4, 4)
        body = diffusion.read_config(folder)
        assert body["phase"] == phase and "world_model" not in body and body["size"] == 32
        assert folder.parent.name == "tiny-dwm"  # the same folder layout: checkpoints/<preset>/<id>
    assert list((data_root / "cache" / "episode_latents").rglob("*.npz"))
    assert not (data_root / "cache" / "episode_codes").exists()

    pre, post = result["pretrain_checkpoint_id"], result["posttrain_checkpoint_id"]
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, ckpts = wh.query("SELECT artifact_id, attrs->>'phase', attrs->>'family', manifest_hash FROM artifacts "
                            "WHERE kind = 'checkpoint' AND attrs->>'model' = 'world_model' ORDER BY 2")
        _, edges = wh.query("SELECT e.child_id, e.relation, p.kind, count(*) FROM edges e "
                            "JOIN artifacts p ON p.artifact_id = e.parent_id WHERE e.child_id IN ($pre, $post) "
                            "GROUP BY ALL ORDER BY 1, 2, 3", {"pre": pre, "post": post})
        _, n_tokens = wh.query("SELECT count(*) FROM artifacts WHERE kind = 'token_shard'")
        _, metrics = wh.query("SELECT subject_id, name, step FROM metrics WHERE subject_id IN ($pre, $post)",
                              {"pre": pre, "post": post})
    assert [(i, p, f) for i, p, f, _ in ckpts] == [(post, "posttrain", "diffusion"), (pre, "pretrain", "diffusion")]
    assert ckpts[0][3] == mh
    assert sorted((c == post, rel, kind, n) for c, rel, kind, n in edges) == sorted([
        (False, "trained_on", "checkpoint", 1), (False, "trained_on", "token_shard", n_tokens[0][0]),
        (True, "posttrained_from", "checkpoint", 1), (True, "trained_on", "checkpoint", 1),
        (True, "trained_on", "episode", 2)])
    assert sorted(metrics) == sorted((c, "train_loss", 3) for c in (pre, post))
    assert lineage_problems(Settings().warehouse_path) == {}

    again = runner.invoke(app, ["train", str(manifest), "--family", "diffusion", "--preset", "tiny-dwm",
                                "--steps", "3", "--post-steps", "3"])
    assert again.exit_code == 0, again.output
    assert f"pre-trained {pre} (already trained), post-trained {post} (already trained)" in " ".join(again.output.split())
    # The autoregressive family finds no discrete tokenizer here; it does not take the continuous one.
    ar = runner.invoke(app, ["train", str(manifest), "--steps", "3", "--post-steps", "3"])
    assert ar.exit_code == 3 and "no discrete tokenizer with token shards" in ar.output

    # evaluate policies --world-model takes the diffusion checkpoint (by id: lineage finds it);
    # closed loop in it is refused in one line.
    from tests.flows.test_evaluate import vision_checkpoint

    grid = tmp_path / "grid.yaml"
    grid.write_text("name: one\ncells: [{name: nominal}]\nepisodes: 1\n")
    done = runner.invoke(app, ["evaluate", "policies", str(manifest), "--grid", str(grid), "--policy", "scripted",
                               "--world-model", post[:16], "--no-detector"])
    assert done.exit_code == 0, done.output
    closed = runner.invoke(app, ["evaluate", "policies", str(manifest), "--grid", str(grid), "--world-model",
                                 post[:16], "--in-world-model", "--policy",
                                 f"vision:{vision_checkpoint(tmp_path, manifest)}"], terminal_width=400)
    assert closed.exit_code == 2 and ("it is a diffusion world model; closed loop (--in-world-model) drives "
                                      "autoregressive world models only") in " ".join(closed.output.split())
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, judged = wh.query("SELECT count(*) FROM edges WHERE parent_id = $p AND relation = 'world_model'",
                             {"p": post})
    assert judged == [(1,)]
