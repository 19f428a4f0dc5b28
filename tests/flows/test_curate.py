"""The curate flow end to end on generated footage, a duplicate and broken inputs."""

import hashlib
import shutil
from pathlib import Path

import pytest

from flows.curate import curate
from tasks.curate import analyse
from schemas.settings import Settings
from warehouse import audit
from warehouse.store import Warehouse

from tasks.manifests import load
from tasks.curate.shards import read_shard
from tasks.mp4 import write_mp4
from tasks.sim.episode import rollout

from tests.support import MANIFESTS, good_videos, lineage_problems, sha256_of

MANIFEST = MANIFESTS / "conveyor_push.yaml"


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """Two simulator episodes (4 s each, one shot), a re-encoded copy of one, and broken inputs."""
    inbox = tmp_path_factory.mktemp("inbox")
    scenario = load(MANIFEST).model_copy(update={"horizon_s": 4.0})
    first, second = (rollout(scenario, seed).frames["overhead"] for seed in (1, 2))
    write_mp4(inbox / "a.mp4", first, 30)
    write_mp4(inbox / "b with space.mp4", second, 30)
    write_mp4(inbox / "c_copy.mp4", first, 30, crf=32)
    (inbox / "broken.mp4").write_bytes(b"\x00\x01garbage" * 300)
    (inbox / "folder.mp4").mkdir()
    return inbox


def _digests(root):
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted((root / "shards").rglob("*.parquet"))}


def test_curate_batch_then_rerun(prefect_harness, data_root, batch, monkeypatch):
    first = curate([str(batch)], str(MANIFEST))
    assert first["status"] == "partial" and first["failed"] == 2 and first["inputs"] == 5
    assert first["counts"]["dedup/duplicate"] == 1
    assert first["clips"] == 2 and first["shards"]
    shards = _digests(data_root)

    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, rejected = wh.query("SELECT stage, reason, detail FROM rejections ORDER BY stage")
        _, analysed = wh.query("SELECT count(*) FROM stage_runs WHERE stage = 'analyse'")
        _, redecoded = wh.query("SELECT attrs->>'redecoded' FROM stage_runs WHERE stage = 'dedup'")
        _, shard_ids = wh.query("SELECT artifact_id FROM artifacts WHERE kind = 'shard'")
        sql, _ = audit.bind("ancestry", {"artifact": "x"})
        _, ancestry = wh.query(sql, {"artifact": shard_ids[0][0]})
    assert ("decode", "unreadable") in {(s, r) for s, r, _ in rejected}
    assert any(s == "dedup" and d.startswith("duplicate of") for s, _, d in rejected)
    assert {r[1] for r in ancestry} >= {"shard", "clip", "raw_video", "manifest"}
    assert analysed == [(3,)]
    # The copy and its original reached dedup's pixel check with frames the analysis pass left
    # undecoded: their sampled frames were decoded exactly, and kept for the re-run.
    assert redecoded == [("2",)]

    def no_decoding(*args, **kwargs):
        raise AssertionError("a re-run decoded frames for dedup")

    monkeypatch.setattr(analyse, "frames_at", no_decoding)
    second = curate([str(batch)], str(MANIFEST))
    assert second["clips"] == first["clips"] and second["counts"] == first["counts"]
    assert _digests(data_root) == shards  # byte-identical shards
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, again = wh.query("SELECT count(*) FROM stage_runs WHERE stage = 'analyse'")
        _, runs = wh.query("SELECT status FROM runs WHERE flow = 'curate'")
    assert again == [(3,)]  # nothing re-analysed: no decoding
    assert runs == [("partial",), ("partial",)]


def _shard_rows(root):
    return [r for p in sorted((root / "shards").rglob("*.parquet")) for r in read_shard(p).select(["clip_id"]).to_pylist()]


def test_a_second_run_into_the_same_bucket_loses_no_clip(prefect_harness, data_root, tmp_path):
    """Issue 26: shards were named by bucket and part number, so a second run's part-00000
    replaced the first run's: its clips were in no shard, and lineage kept two rows for one
    path, one with a sha256 the file no longer had."""
    first = curate([str(p) for p in good_videos(tmp_path / "a", seeds=(0,))])
    second = curate([str(p) for p in good_videos(tmp_path / "b", seeds=(2,))])
    assert first["clips"] and second["clips"]
    assert {Path(u).parent for u in first["shards"]} == {Path(u).parent for u in second["shards"]}  # one bucket
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, kept = wh.query("SELECT artifact_id FROM artifacts WHERE kind = 'clip' AND uri IS NOT NULL")
        _, rows = wh.query("SELECT uri, sha256 FROM artifacts WHERE kind = 'shard'")
    assert len(kept) == first["clips"] + second["clips"]
    assert sorted(r["clip_id"] for r in _shard_rows(data_root)) == sorted(k for k, in kept)
    assert len({uri for uri, _ in rows}) == len(rows) == 2
    assert all(sha256_of(data_root / uri) == sha for uri, sha in rows)
    assert lineage_problems(Settings().warehouse_path) == {}


def test_old_layout_shards_are_renamed_with_their_rows_when_curate_starts(prefect_harness, data_root, tmp_path):
    """Shards written before issue 26 (part-NNNNN.parquet) move to their names by content, and
    the lineage rows with their bytes follow; a file no row knows moves too and is reported."""
    done = curate([str(p) for p in good_videos(tmp_path / "a", seeds=(0,))])
    (new_uri,) = done["shards"]
    old_uri = str(Path(new_uri).with_name("part-00000.parquet"))
    (data_root / new_uri).rename(data_root / old_uri)
    stray = data_root / "shards" / "unscoped" / "lt240p" / "ge60s" / "part-00003.parquet"
    stray.parent.mkdir(parents=True)
    shutil.copyfile(data_root / old_uri, stray)
    with Warehouse(Settings().warehouse_path) as wh, wh.transaction() as con:
        con.execute("UPDATE artifacts SET uri = ? WHERE uri = ?", [old_uri, new_uri])

    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"\x00junk" * 100)
    curate([str(junk)])
    assert (data_root / new_uri).is_file() and not (data_root / old_uri).exists()
    moved = stray.with_name(f"part-00003-{sha256_of(data_root / new_uri)[:16]}.parquet")
    assert moved.is_file() and not stray.exists()  # nothing deleted
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, rows = wh.query("SELECT uri FROM artifacts WHERE kind = 'shard'")
    assert rows == [(new_uri,)]
