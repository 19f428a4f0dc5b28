"""`worldline train-transfer` and `worldline transfer` end to end: one push_closeup episode of a
second simulated with its controls, a `tiny` model saved to a folder, clips, labels, lineage,
skips, and every bad input refused in one line before anything is written."""

import json

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from flows.cli import app
from flows.params import ParamsError
from schemas.settings import Settings
from tasks.transfer.train import TrainConfig, new_model, save_transfer
from tasks.video.read import display_frames, probe
from warehouse import audit
from warehouse.store import Warehouse

from tests.support import MANIFESTS

runner = CliRunner()
SIDE = 32


def lines(result) -> list[str]:
    return [line for line in result.output.splitlines() if line.strip()]


def query(sql: str) -> list[tuple]:
    with Warehouse(Settings().warehouse_path, read_only=True) as warehouse:
        return warehouse.query(sql)[1]


@pytest.fixture(scope="module")
def world(prefect_harness, tmp_path_factory):
    """(data root, manifest, episode folder, tiny model folder): the module's own data root."""
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("transfer-root")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("WORLDLINE_DATA_ROOT", str(root))
        manifest = root.parent / "closeup.yaml"
        manifest.write_text((MANIFESTS / "push_closeup.yaml").read_text().replace("horizon_s: 6.0", "horizon_s: 1.0"))
        result = runner.invoke(app, ["simulate", str(manifest), "--episodes", "1", "--controls"])
        assert result.exit_code == 0, result.output
        (episode,) = (root / "episodes").glob("*/episode_000000")
        model = root.parent / "tiny-model"
        save_transfer(new_model(TrainConfig(preset="tiny")), model, extra={"size": SIDE, "camera": "side"})
        yield root, manifest, episode, model


def test_a_transfer_writes_each_look_beside_its_labels_in_lineage_and_skips_on_a_rerun(world):
    root, _, episode, model = world
    result = runner.invoke(app, ["transfer", str(episode), "--model", str(model), "--look", "dim,very dim"])
    assert result.exit_code == 0 and "2 clips written, 0 done before" in result.output, result.output
    videos = sorted((root / "transfer").glob("*/episode_000000/*/*/side.mp4"))
    assert [v.parts[-3] for v in videos] == ["dim", "very-dim"]
    source = list(display_frames(episode / "side.mp4"))
    for video in videos:
        frames = np.stack(list(display_frames(video)))
        assert frames.shape == (len(source), SIDE, SIDE, 3) and probe(video).fps == probe(episode / "side.mp4").fps
        for name in ("steps.parquet", "meta.json"):  # the labels, byte for byte
            assert (video.parent / name).read_bytes() == (episode / name).read_bytes()
        info = json.loads((video.parent / "transfer.json").read_text())
        assert info["look"] in ("dim", "very dim") and info["size"] == SIDE and info["source"].startswith("episodes/")
    edges = query("SELECT e.relation, p.kind, count(*) FROM edges e JOIN artifacts p ON p.artifact_id = e.parent_id "
                  "JOIN artifacts c ON c.artifact_id = e.child_id WHERE c.kind = 'transferred_video' GROUP BY ALL "
                  "ORDER BY 1")
    assert edges == [("controlled_by", "control", 4), ("transferred_by", "transfer_model", 2),
                     ("transferred_from", "episode_video", 2)]
    guarded = query("SELECT m.name, count(*) FROM metrics m JOIN artifacts a ON a.artifact_id = m.subject_id "
                    "WHERE a.kind = 'transferred_video' AND m.name IN ('guard_text_matches', 'guard_faces_boxes') "
                    "GROUP BY 1 ORDER BY 1")
    assert guarded == [("guard_faces_boxes", 2), ("guard_text_matches", 2)]

    (clip,) = query("SELECT artifact_id FROM artifacts WHERE kind = 'transferred_video' AND attrs->>'look' = 'dim'")
    sql, _ = audit.bind("ancestry", {"artifact": "x"})
    with Warehouse(Settings().warehouse_path, read_only=True) as warehouse:
        kinds = {r[1] for r in warehouse.query(sql, {"artifact": clip[0]})[1]}
    assert kinds == {"transferred_video", "episode_video", "episode", "manifest", "control", "transfer_model"}

    again = runner.invoke(app, ["transfer", str(episode), "--model", str(model), "--look", "dim,very dim"])
    assert again.exit_code == 0 and "0 clips written, 2 done before" in again.output, again.output
    verified = runner.invoke(app, ["verify", "--format", "json"])
    assert verified.exit_code == 0, verified.output  # every transferred file has the bytes lineage holds


def test_each_bad_input_is_refused_in_one_line_before_anything_is_written(world, tmp_path):
    root, _, episode, model = world
    not_transfer = tmp_path / "tokenizer"
    not_transfer.mkdir()
    (not_transfer / "config.json").write_text(json.dumps({"tokenizer": {"name": "t"}}))
    shifted = tmp_path / "episode"
    shifted.mkdir()
    for path in episode.rglob("*"):
        if path.is_file():
            (shifted / path.relative_to(episode)).parent.mkdir(parents=True, exist_ok=True)
            (shifted / path.relative_to(episode)).write_bytes(path.read_bytes())
    with np.load(episode / "controls" / "side.depth.npz") as npz:
        arrays = dict(npz)
    np.savez_compressed(shifted / "controls" / "side.depth.npz", **{**arrays, "depth_mm": arrays["depth_mm"][1:]})
    base = ["transfer", str(episode), "--model", str(model)]
    cases = [(base + ["--look", "sepia"], "--look: unknown look 'sepia'"),
             (base + ["--look", "dim,k1ll"], "--look: blocked term 'kill'"),
             (["transfer", str(episode), "--model", str(not_transfer), "--look", "dim"], "not a transfer checkpoint"),
             (base + ["--look", "dim", "--camera", "wrist"], "camera 'wrist' is not one of the episode's"),
             (base + ["--look", "dim", "--weights", "normals=1"], "--weights: 'normals=1'"),
             (["transfer", str(episode), "--model", "abcdef123456", "--look", "dim"],
              "--model: transfer model abcdef123456: no transfer model checkpoint with that id in lineage"),
             (["transfer", str(tmp_path / "nothing"), "--model", str(model), "--look", "dim"],
              "nothing: no such file or folder"),
             (["train-transfer", str(world[1]), "--camera", "wrist"], "--camera: camera 'wrist' is not in manifest"),
             (base + ["--look", "dim", "--reference", str(episode / "side.mp4")],
              "--reference: the model " + str(model)),
             (["transfer", str(shifted), "--model", str(model), "--look", "dim"], "side.depth.npz: ")]
    before = sorted(p for p in (root / "transfer").rglob("*")) if (root / "transfer").exists() else []
    runs = query("SELECT count(*) FROM runs")
    for args, said in cases:
        refused = runner.invoke(app, args, terminal_width=400)
        assert refused.exit_code == 2 and len(lines(refused)) == 1 and said in lines(refused)[0], refused.output
    assert "frames, the episode's side video has" in lines(refused)[0]
    after = sorted(p for p in (root / "transfer").rglob("*")) if (root / "transfer").exists() else []
    assert after == before and query("SELECT count(*) FROM runs") == runs

    # No model given and none trained in this data root: a step not built yet (3), as `evaluate physics` says it.
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("WORLDLINE_DATA_ROOT", str(tmp_path / "untrained"))
        unbuilt = runner.invoke(app, ["transfer", str(episode), "--look", "dim"], terminal_width=400)
    assert unbuilt.exit_code == 3 and lines(unbuilt) == [
        "no transfer model in lineage: run `worldline train-transfer` first, or give --model"], unbuilt.output

    from flows.transfer import transfer  # a deployment run gets the same checks, as ParamsError

    with pytest.raises(ParamsError, match="^look: unknown look 'sepia'"):
        transfer.fn(source=str(episode), model=str(model), look="sepia")
    with pytest.raises(ParamsError, match="camera 'wrist'"):
        transfer.fn(source=str(episode), model=str(model), look="dim", camera="wrist")


def test_train_transfer_records_a_transfer_model_that_transfer_runs(world):
    root, manifest, episode, _ = world
    args = ["train-transfer", str(manifest), "--seeds", "1", "--preset", "tiny", "--steps", "3", "--size", str(SIDE)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0 and "train PSNR" in result.output, result.output
    (weights,) = (root / "checkpoints").glob("transfer-tiny/*/model.safetensors")
    rows = query("SELECT a.artifact_id, e.relation, e.parent_id, a.attrs->>'preset' FROM artifacts a "
                 "JOIN edges e ON e.child_id = a.artifact_id WHERE a.kind = 'transfer_model' "
                 "AND a.uri LIKE 'checkpoints/%'")
    (model_id, relation, parent, name), = rows
    (manifest_hash,) = query("SELECT manifest_hash FROM manifests WHERE name = 'push-closeup'")
    assert (relation, parent, name) == ("trained_on", manifest_hash[0], "tiny")
    assert query(f"SELECT count(*) FROM metrics WHERE subject_id = '{model_id}' AND name = 'train_loss'") == [(1,)]
    again = runner.invoke(app, args)
    assert again.exit_code == 0 and "trained before" in again.output, again.output

    done = runner.invoke(app, ["transfer", str(manifest), "--look", "textures"])  # the newest trained model
    assert done.exit_code == 0 and "1 clips written" in done.output, done.output
    assert query("SELECT e.parent_id FROM edges e JOIN artifacts c ON c.artifact_id = e.child_id "
                 "WHERE e.relation = 'transferred_by' AND c.attrs->>'look' = 'textures'") == [(model_id,)]
    by_id = runner.invoke(app, ["transfer", str(episode), "--model", model_id[:12], "--look", "textures"])
    assert by_id.exit_code == 0 and "0 clips written, 1 done before" in by_id.output, by_id.output
    assert weights.parent.name == model_id

    temporal = runner.invoke(app, [*args, "--temporal", "0"])  # without the temporal loss: another training
    assert temporal.exit_code == 0 and "train PSNR" in temporal.output, temporal.output
    folders = {p.parent.name for p in (root / "checkpoints").glob("transfer-tiny/*/model.safetensors")}
    assert len(folders) == 2 and model_id in folders
    train_config = lambda folder: json.loads((root / "checkpoints" / "transfer-tiny" / folder / "config.json")  # noqa: E731
                                             .read_text())["train"]
    assert train_config(model_id)["temporal"] == 1.0 and train_config(model_id)["clip_frames"] == 3  # the defaults
    assert train_config((folders - {model_id}).pop())["temporal"] == 0.0



def test_an_episode_holding_another_episodes_video_is_not_transferred(world, tmp_path):
    """Its step table is copied beside the clip as its labels, so the video must be one this very
    episode rendered. A panel's nominal cell is byte for byte the manifest's own episodes, so its
    videos have no lineage rows of their own, and a copy of another episode's video there matched
    that episode's row and was transferred under the wrong labels."""
    import filecmp
    import shutil

    root, manifest, episode, model = world
    assert runner.invoke(app, ["simulate", str(manifest), "--episodes", "2"]).exit_code == 0
    grid = tmp_path / "grid.yaml"
    grid.write_text("name: nominal-only\ncells:\n  - name: nominal\nepisodes: 2\n")
    result = runner.invoke(app, ["panels", str(manifest), "--grid", str(grid)])
    assert result.exit_code == 0, result.output
    (cell,) = [f for f in (root / "episodes").iterdir() if f != episode.parent and filecmp.cmp(
        f / "episode_000001" / "side.mp4", episode.parent / "episode_000001" / "side.mp4", shallow=False)]
    shutil.copyfile(cell / "episode_000001" / "side.mp4", cell / "episode_000000" / "side.mp4")
    refused = runner.invoke(app, ["transfer", str(cell / "episode_000000"), "--model", str(model), "--look", "dim",
                                  "--weights", "depth=0,segmentation=0"])
    assert refused.exit_code == 5, refused.output
    said = lines(refused)[-1]
    assert said.startswith(f"{cell / 'episode_000000' / 'side.mp4'}: sha256 ")
    assert "is not a video lineage recorded for this episode" in said, said
    assert not list((root / "transfer").glob(f"{cell.name}*"))
