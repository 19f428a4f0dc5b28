"""The tokenize flow on shards the real curate flow made from a simulator episode."""

import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from flows.cli import app
from flows.curate import curate
from flows.tokenize import tokenize
from models.tokenizer import VideoTokenizer, preset
from schemas.settings import Settings
from tasks.manifests import load
from tasks.mp4 import write_mp4
from tasks.sim.episode import rollout
from tasks.tokenize import tokens
from tests.support import MANIFESTS, lineage_problems
from warehouse import audit
from warehouse.store import Warehouse

MANIFEST = MANIFESTS / "conveyor_push.yaml"


@pytest.fixture(scope="module")
def inbox(tmp_path_factory):
    """One 4 s simulator episode (one shot, 128 x 128), and a curate config that tags overlay
    text instead of rejecting (this test is about tokenizing, not about the text filter)."""
    folder = tmp_path_factory.mktemp("inbox")
    scenario = load(MANIFEST).model_copy(update={"horizon_s": 4.0})
    write_mp4(folder / "episode.mp4", rollout(scenario, 1).frames["overhead"], 30)
    config = tmp_path_factory.mktemp("config") / "curate.yaml"
    config.write_text("overlay_text: {action: tag}\n")
    return folder, config


def test_tokenize_trains_encodes_and_records_lineage(prefect_harness, data_root, inbox):
    folder, config = inbox
    curated = curate([str(folder)], str(MANIFEST), str(config))
    assert curated["clips"] >= 1 and curated["shards"]
    mh = curated["manifest_hash"]

    result = tokenize(mh, "tiny-dv4x8x8", steps=3, size=32, batch_size=2)
    assert result["trained"] and len(result["token_shards"]) == len(curated["shards"])
    folder = data_root / result["checkpoint"]
    assert (folder / "model.safetensors").is_file() and (folder / "config.json").is_file()
    assert list((folder / "tensorboard").glob("events.out.tfevents.*"))

    rows = pq.read_table(data_root / result["token_shards"][0]).to_pylist()
    assert len(rows) >= 1 and rows[0]["grid"][1:] == [4, 4]
    assert all(0 <= c < 1000 for r in rows for c in r["codes"])

    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, ckpt = wh.query("SELECT artifact_id, uri, manifest_hash FROM artifacts WHERE kind = 'checkpoint'")
        _, trained_on = wh.query("SELECT e.parent_id FROM edges e JOIN artifacts a ON a.artifact_id = e.parent_id "
                                 "WHERE e.relation = 'trained_on' AND a.kind = 'shard'")
        _, shard_ids = wh.query("SELECT artifact_id FROM artifacts WHERE kind = 'shard'")
        _, token_edges = wh.query("SELECT e.relation, p.kind FROM edges e JOIN artifacts t ON t.artifact_id = e.child_id "
                                  "JOIN artifacts p ON p.artifact_id = e.parent_id WHERE t.kind = 'token_shard' ORDER BY 1")
        _, metrics = wh.query("SELECT name, count(*) FROM metrics WHERE subject_id IN "
                              "(SELECT artifact_id FROM artifacts WHERE kind IN ('checkpoint', 'token_shard')) GROUP BY 1 ORDER BY 1")
        _, token_id = wh.query("SELECT artifact_id FROM artifacts WHERE kind = 'token_shard' LIMIT 1")
        sql, _ = audit.bind("ancestry", {"artifact": "x"})
        _, ancestry = wh.query(sql, {"artifact": token_id[0][0]})
        _, runs = wh.query("SELECT status FROM runs WHERE flow = 'tokenize'")
    assert len(ckpt) == 1 and ckpt[0][0] == result["checkpoint_id"] and ckpt[0][2] == mh
    assert sorted(p for (p,) in trained_on) == sorted(s for (s,) in shard_ids)
    assert token_edges == sorted([("encoded_by", "checkpoint"), ("tokens_of", "shard")] * len(curated["shards"]))
    assert dict(metrics) == {"psnr": len(curated["shards"]), "train_loss": 1, "train_psnr": 1}  # logged at the last step
    assert {r[1] for r in ancestry} >= {"checkpoint", "shard", "clip", "raw_video", "manifest"}
    assert runs == [("completed",)]
    assert lineage_problems(Settings().warehouse_path) == {}

    again = tokenize(mh, "tiny-dv4x8x8", steps=3, size=32, batch_size=2)
    assert again["checkpoint_id"] == result["checkpoint_id"] and not again["trained"] and again["token_shards"] == []

    # Continue training from that checkpoint, with the motion levers on: a new checkpoint that starts from its weights.
    more = tokenize(mh, "tiny-dv4x8x8", steps=3, size=32, batch_size=2, motion_weight=4.0, focus_crops=2,
                    init=result["checkpoint_id"][:12])
    assert more["trained"] and more["checkpoint_id"] != result["checkpoint_id"]
    first, second = (tokens.load_checkpoint(data_root / r["checkpoint"]).state_dict() for r in (result, more))
    fresh = VideoTokenizer(preset("tiny-dv4x8x8")).state_dict()
    assert max((second[k] - first[k]).abs().max().item() for k in first) < 0.01  # 3 warm-up steps away
    assert max((fresh[k] - first[k]).abs().max().item() for k in first) > 0.05
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, edges = wh.query("SELECT parent_id, relation FROM edges WHERE child_id = $c AND relation = 'continued_from'",
                            {"c": more["checkpoint_id"]})
    assert edges == [(result["checkpoint_id"], "continued_from")]
    with pytest.raises(ValueError, match="not preset 'tiny-cv4x8x8'"):
        tokenize(mh, "tiny-cv4x8x8", steps=3, size=32, batch_size=2, init=result["checkpoint_id"])
    with pytest.raises(FileNotFoundError, match="no tokenizer checkpoint with that id"):
        tokenize(mh, "tiny-dv4x8x8", steps=3, size=32, batch_size=2, init="0123456789ab")


def test_cli_refuses_bad_tokenize_arguments(tmp_path):
    runner = CliRunner()
    bad = runner.invoke(app, ["tokenize", str(tmp_path), "--preset", "huge"])
    assert bad.exit_code == 2 and "unknown tokenizer preset" in bad.output
    empty = runner.invoke(app, ["tokenize", str(tmp_path)])
    assert empty.exit_code == 2 and "no shard files" in empty.output
    odd = runner.invoke(app, ["tokenize", str(tmp_path), "--size", "36"])
    assert odd.exit_code == 2 and "spatial compression" in odd.output
    crop = runner.invoke(app, ["tokenize", str(tmp_path), "--crop", "20"])
    assert crop.exit_code == 2 and "--crop: 20" in crop.output
    big = runner.invoke(app, ["tokenize", str(tmp_path), "--crop", "128"])
    assert big.exit_code == 2 and "larger than --size" in big.output


def _flip(path, at: float = 0.5) -> None:
    data = bytearray(path.read_bytes())
    data[int(len(data) * at)] ^= 0xFF
    path.write_bytes(bytes(data))


def _counts() -> dict:
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        return {k: v for k, v in wh.counts().items() if k not in ("runs",)}


def test_tokenize_refuses_a_changed_shard_and_one_curate_never_wrote(prefect_harness, data_root, inbox, tmp_path):
    """Issue 26: a shard whose bytes changed trained a tokenizer and was registered as a new,
    parentless artifact, so the checkpoint's ancestry lost its clips and raw video."""
    from schemas.errors import InvalidInput, TamperedArtifact

    folder, config = inbox
    curated = curate([str(folder)], str(MANIFEST), str(config))
    shard = data_root / curated["shards"][0]
    _flip(shard)
    before = _counts()
    with pytest.raises(TamperedArtifact) as caught:
        tokenize(curated["manifest_hash"], "tiny-dv4x8x8", steps=3, size=32, batch_size=2)
    message = str(caught.value)
    assert "\n" not in message and message.startswith(f"{shard}: sha256 ") and "run `worldline verify`" in message
    assert _counts() == before  # nothing registered, nothing trained
    assert not (data_root / "checkpoints").exists()

    stranger = tmp_path / "elsewhere" / "part-00000.parquet"  # bytes lineage never recorded, outside the root
    stranger.parent.mkdir()
    stranger.write_bytes(shard.read_bytes())
    with pytest.raises(InvalidInput, match=f"{stranger}: lineage has no curated shard with these bytes"):
        tokenize(str(stranger.parent), "tiny-dv4x8x8", steps=3, size=32, batch_size=2)
    assert _counts() == before


def test_a_rerun_does_not_encode_with_a_tokenizer_whose_weights_changed(prefect_harness, data_root, inbox):
    """Training skipped (done before), a missing token shard was encoded again with whatever the
    weights file held, and recorded: the checkpoint's bytes are checked first (exit 5)."""
    from schemas.errors import TamperedArtifact

    folder, config = inbox
    curated = curate([str(folder)], str(MANIFEST), str(config))
    first = tokenize(curated["manifest_hash"], "tiny-dv4x8x8", steps=3, size=32, batch_size=2)
    weights = data_root / first["checkpoint"] / "model.safetensors"
    (data_root / first["token_shards"][0]).unlink()
    _flip(weights, 0.9)
    before = _counts()
    with pytest.raises(TamperedArtifact, match=rf"^{weights}: sha256 \w+ differs from lineage's"):
        tokenize(curated["manifest_hash"], "tiny-dv4x8x8", steps=3, size=32, batch_size=2)
    assert _counts() == before and not (data_root / first["token_shards"][0]).exists()
    _flip(weights, 0.9)  # the bytes lineage recorded: encoded again as before
    again = tokenize(curated["manifest_hash"], "tiny-dv4x8x8", steps=3, size=32, batch_size=2)
    assert again["token_shards"] == first["token_shards"] and (data_root / first["token_shards"][0]).is_file()


def test_curate_encodes_a_changed_clip_again_instead_of_sharding_it(prefect_harness, data_root, inbox):
    """Issue 26: a re-run reused clip files whose encode stage was done and re-hashed whatever
    was on disk into new shards. Now a reused clip must match lineage; one that does not is
    encoded again from its (intact) source, which restores the recorded bytes."""
    folder, config = inbox
    curated = curate([str(folder)], str(MANIFEST), str(config))
    clips = sorted((data_root / "clips").rglob("*.mp4"))
    assert clips
    recorded = {c: c.read_bytes() for c in clips}
    shards_before = {s: (data_root / s).read_bytes() for s in curated["shards"]}
    clips[0].write_bytes(clips[-1].read_bytes() if len(clips) > 1 else b"not the clip" * 100)  # swapped

    again = curate([str(folder)], str(MANIFEST), str(config))
    assert again["status"] == "completed" and again["clips"] == curated["clips"]
    assert {c: c.read_bytes() for c in clips} == recorded  # encoded again: the bytes lineage recorded
    assert sorted(again["shards"]) == sorted(curated["shards"])
    assert {s: (data_root / s).read_bytes() for s in again["shards"]} == shards_before
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, shards = wh.query("SELECT count(*) FROM artifacts WHERE kind = 'shard'")
    assert shards == [(len(curated["shards"]),)]
    assert lineage_problems(Settings().warehouse_path) == {}


def test_a_clip_in_two_shards_is_trained_on_and_tokenized_once(prefect_harness, data_root, inbox, tmp_path):
    """Shards are named by content, so curating A, then A and B, leaves A in two shards of one
    bucket: the tokenizer takes it once."""
    folder, config = inbox
    first = curate([str(folder)], str(MANIFEST), str(config))
    other = tmp_path / "other"
    other.mkdir()
    scenario = load(MANIFEST).model_copy(update={"horizon_s": 4.0})
    write_mp4(other / "episode2.mp4", rollout(scenario, 2).frames["overhead"], 30)
    both = curate([str(folder), str(other)], str(MANIFEST), str(config))
    assert len(set(first["shards"]) | set(both["shards"])) == 2  # A alone, then A with B
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, (n_clips,) = wh.query("SELECT count(*) FROM artifacts WHERE kind = 'clip' AND uri IS NOT NULL")

    result = tokenize(first["manifest_hash"], "tiny-dv4x8x8", steps=2, size=32, batch_size=2)
    assert result["clips"] == n_clips[0]
    ids = [r["clip_id"] for uri in result["token_shards"] for r in pq.read_table(data_root / uri).to_pylist()]
    assert sorted(ids) == sorted(set(ids)) and len(ids) == n_clips[0]
