"""Parquet shards: explicit schema, buckets, order, size caps, byte-identical re-runs, lineage."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from schemas import paths
from schemas.hashing import stable_id
from schemas.records import ClipRecord
from schemas.errors import EnvironmentFault
from tasks import faults
from tasks.curate.shards import (
    SHARD_SCHEMA,
    SHARD_SCHEMA_V1,
    ShardConfig,
    ShardError,
    legacy_shards,
    length_bucket,
    read_shard,
    remove_stale_temporaries,
    rename_legacy,
    resolution_bucket,
    scores_of,
    shard_lineage,
    write_shards,
)

MANIFEST = "ab" * 32
SIZES = ((1280, 720), (640, 360), (320, 240), (720, 1280))
DURATIONS = (2.5, 4.0, 7.5, 12.0, 45.0)


def _clips(root: Path, n: int = 20) -> list[ClipRecord]:
    """n clips over several sizes and lengths; clip i's 'MP4' is i-dependent bytes under root."""
    clips = []
    for i in range(n):
        w, h = SIZES[i % len(SIZES)]
        duration = DURATIONS[(i * 3) % len(DURATIONS)]
        data = bytes([i % 251]) * (1000 + 37 * i)
        cid = f"clip{i:03d}"
        rel = paths.CLIP_FILE.format(source_id="src0", clip_id=cid)
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(data)
        clips.append(ClipRecord(
            clip_id=cid, source_id="src0", source_uri="raw/raw_0000.mp4", start_frame=10 * i,
            end_frame=10 * i + int(duration * 30), start_s=i / 3, end_s=i / 3 + duration, fps=30.0,
            width=w, height=h, scores={"quality": i / n, "motion_mean": 2.0 + i}, tags=("camera:still", f"n:{i}"),
            caption=f"clip number {i}", phash="0f" * 40, dedup_group=cid, uri=rel,
            sha256=hashlib.sha256(data).hexdigest(), bytes=len(data), manifest_hash=MANIFEST,
        ))
    return clips


def test_bucket_names():
    assert [resolution_bucket(w, h) for w, h in SIZES] == ["720p", "360p", "240p", "720p"]
    assert resolution_bucket(3840, 2160) == "2160p" and resolution_bucket(256, 144) == "lt240p"
    assert resolution_bucket(1920, 1079) == "720p"
    assert [length_bucket(d) for d in (1.0, 2.0, 4.99, 5.0, 29.9, 30.0, 59.0, 60.0, 600.0)] == [
        "lt2s", "2-5s", "2-5s", "5-10s", "10-30s", "30-60s", "30-60s", "ge60s", "ge60s"]
    custom = ShardConfig(length_edges=(1.5, 4.0))
    assert [length_bucket(d, custom) for d in (1.0, 2.0, 9.0)] == ["lt1.5s", "1.5-4s", "ge4s"]
    with pytest.raises(ValueError, match="increasing"):
        ShardConfig(length_edges=(5.0, 2.0))


def test_rows_round_trip_in_bucket_order(tmp_path):
    clips = _clips(tmp_path)
    shards = write_shards(clips, tmp_path, MANIFEST)
    by_id = {c.clip_id: c for c in clips}
    seen = []
    assert [(s.resolution_bucket, s.length_bucket) for s in shards] == sorted({(s.resolution_bucket, s.length_bucket) for s in shards})
    for shard in shards:
        assert shard.uri == paths.SHARD_FILE.format(manifest_hash=MANIFEST, resolution=shard.resolution_bucket,
                                                    length=shard.length_bucket, index=0, sha256=shard.sha256)
        path = tmp_path / shard.uri
        assert shard.bytes == path.stat().st_size and shard.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
        table = read_shard(path)
        assert table.schema.equals(SHARD_SCHEMA, check_metadata=False)
        rows = table.to_pylist()
        assert [r["clip_id"] for r in rows] == list(shard.clip_ids)
        assert [(r["duration_s"], r["clip_id"]) for r in rows] == sorted((r["duration_s"], r["clip_id"]) for r in rows)
        for row in rows:
            clip = by_id[row["clip_id"]]
            assert resolution_bucket(clip.width, clip.height) == shard.resolution_bucket
            assert length_bucket(clip.end_s - clip.start_s) == shard.length_bucket
            assert row["clip_bytes"] == (tmp_path / clip.uri).read_bytes()
            assert scores_of(row) == clip.scores and tuple(row["tags"]) == clip.tags
            assert (row["start_frame"], row["end_frame"], row["width"], row["height"]) == (
                clip.start_frame, clip.end_frame, clip.width, clip.height)
            assert (row["caption"], row["sha256"], row["clip_uri"], row["manifest_hash"]) == (
                clip.caption, clip.sha256, clip.uri, MANIFEST)
            seen.append(row["clip_id"])
    assert sorted(seen) == sorted(by_id)
    leftovers = [p for p in tmp_path.rglob("*") if p.name.endswith(".tmp")]
    assert not leftovers


def test_same_records_give_identical_bytes(tmp_path):
    clips = _clips(tmp_path / "a")
    first = write_shards(clips, tmp_path / "a", MANIFEST)
    again = write_shards(list(reversed(clips)), tmp_path / "a", MANIFEST)
    assert first == again
    # A second root (same clip bytes) gives the same files too: nothing depends on time or place.
    clips_b = _clips(tmp_path / "b")
    assert [s.sha256 for s in write_shards(clips_b, tmp_path / "b", MANIFEST)] == [s.sha256 for s in first]
    changed = [c.model_copy(update={"caption": c.caption + "!"}) if c.clip_id == "clip000" else c for c in clips]
    assert [s.sha256 for s in write_shards(changed, tmp_path / "a", MANIFEST)] != [s.sha256 for s in first]


def test_size_caps_split_files(tmp_path):
    clips = [c.model_copy(update={"width": 640, "height": 360, "end_s": c.start_s + 3.0}) for c in _clips(tmp_path, 10)]
    by_count = write_shards(clips, tmp_path, MANIFEST, ShardConfig(max_clips=3))
    assert [s.n_clips for s in by_count] == [3, 3, 3, 1]
    assert [Path(s.uri).name for s in by_count] == [f"part-{i:05d}-{s.sha256[:16]}.parquet" for i, s in enumerate(by_count)]
    # About 1.0-1.4 kB of clip bytes plus ~512 B of row: a 4 kB cap holds two rows.
    by_size = write_shards(clips, tmp_path, "cd" * 32, ShardConfig(max_bytes=4000))
    assert all(s.n_clips == 2 for s in by_size) and len(by_size) == 5
    assert [c for s in by_size for c in s.clip_ids] == [c for s in by_count for c in s.clip_ids]


def test_without_clip_bytes(tmp_path):
    clips = [c.model_copy(update={"uri": None, "sha256": None}) for c in _clips(tmp_path, 4)]
    with pytest.raises(ShardError, match=r"clip clip\d{3}: no uri"):
        write_shards(clips, tmp_path, MANIFEST)
    shards = write_shards(clips, tmp_path, MANIFEST, ShardConfig(embed_clips=False))
    rows = [r for s in shards for r in read_shard(tmp_path / s.uri).to_pylist()]
    assert len(rows) == 4 and all(r["clip_bytes"] is None and r["clip_uri"] is None for r in rows)


def test_bad_inputs_are_named(tmp_path):
    clips = _clips(tmp_path, 3)
    (tmp_path / clips[1].uri).write_bytes(b"tampered")
    with pytest.raises(ShardError, match=r"clip001\.mp4: sha256 differs .* clip001"):
        write_shards(clips, tmp_path, MANIFEST)
    (tmp_path / clips[1].uri).unlink()
    with pytest.raises(ShardError, match=r"clip001\.mp4: cannot read clip clip001"):
        write_shards(clips, tmp_path, MANIFEST)
    with pytest.raises(ShardError, match="marked rejected, e.g. clip000"):
        write_shards([clips[0].model_copy(update={"kept": False})], tmp_path, MANIFEST)
    with pytest.raises(ShardError, match="repeat"):
        write_shards([clips[0], clips[0]], tmp_path, MANIFEST)


def test_read_shard_refuses_other_schemas(tmp_path):
    good = tmp_path / write_shards(_clips(tmp_path, 2), tmp_path, MANIFEST)[0].uri
    table = pq.read_table(good)
    cases = {
        "missing.parquet": (table.drop_columns(["caption"]), "column 'caption' is missing"),
        "retyped.parquet": (table.set_column(table.schema.get_field_index("width"), pa.field("width", pa.int64(), nullable=False),
                                             table["width"].cast(pa.int64())), "column 'width' is int64 not null, expected int32"),
        "extra.parquet": (table.append_column("surprise", pa.array([1] * table.num_rows)), "unexpected column 'surprise'"),
    }
    for name, (bad, message) in cases.items():
        pq.write_table(bad, tmp_path / name)
        with pytest.raises(ShardError, match=f"{name}: not a Worldline shard: {message}"):
            read_shard(tmp_path / name)
    (tmp_path / "junk.parquet").write_bytes(b"not parquet at all")
    with pytest.raises(ShardError, match="junk.parquet: not a readable Parquet file"):
        read_shard(tmp_path / "junk.parquet")


def test_lineage_links_every_clip_to_its_shard(tmp_path):
    clips = _clips(tmp_path)
    shards = write_shards(clips, tmp_path, MANIFEST)
    batch = shard_lineage(shards, "run-1")
    assert [a.artifact_id for a in batch.artifacts] == [s.shard_id for s in shards]
    assert all(a.kind == "shard" and a.stage_run_id == "run-1" and a.manifest_hash == MANIFEST for a in batch.artifacts)
    assert {(a.sha256, a.bytes) for a in batch.artifacts} == {(s.sha256, s.bytes) for s in shards}
    assert sorted((e.parent_id, e.relation) for e in batch.edges) == sorted((c.clip_id, "shard_of") for c in clips)
    owner = {c: s.shard_id for s in shards for c in s.clip_ids}
    assert all(owner[e.parent_id] == e.child_id for e in batch.edges)
    assert shards[0].shard_id == stable_id("shard", shards[0].uri, shards[0].sha256)


def test_write_speed(tmp_path):
    """200 clips of 200 kB (40 MB): a loose floor that still catches an accidental quadratic or re-encode."""
    clips = []
    for c in _clips(tmp_path, 200):
        data = os.urandom(200_000)
        (tmp_path / c.uri).write_bytes(data)
        clips.append(c.model_copy(update={"sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}))
    import time
    start = time.perf_counter()
    shards = write_shards(clips, tmp_path, MANIFEST)
    seconds = time.perf_counter() - start
    total = sum(s.bytes for s in shards)
    assert total > 200 * 200_000
    assert total / seconds > 10e6, f"{total / seconds / 1e6:.1f} MB/s"


def _clip_ids(root: Path) -> list[str]:
    return sorted(c for p in (root / "shards").rglob("*.parquet") for c in read_shard(p)["clip_id"].to_pylist())


def test_a_later_run_into_the_same_bucket_adds_files_and_overwrites_none(tmp_path):
    """Issue 26: shards were named by bucket and part number only, so a second run's part-00000
    replaced the first run's and its clips were in no shard any more."""
    clips = [c.model_copy(update={"width": 640, "height": 360, "end_s": c.start_s + 3.0}) for c in _clips(tmp_path, 4)]
    first = write_shards(clips[:2], tmp_path, MANIFEST)
    second = write_shards(clips[2:], tmp_path, MANIFEST)
    assert len(first) == len(second) == 1 and Path(first[0].uri).parent == Path(second[0].uri).parent
    assert first[0].uri != second[0].uri
    assert _clip_ids(tmp_path) == sorted(c.clip_id for c in clips)
    for shard in first + second:
        assert hashlib.sha256((tmp_path / shard.uri).read_bytes()).hexdigest() == shard.sha256
    assert write_shards(clips[:2], tmp_path, MANIFEST) == first  # the same clips: the same file, rewritten


def test_old_layout_shards_are_found_and_renamed_by_content(tmp_path):
    shards = write_shards(_clips(tmp_path, 8), tmp_path, MANIFEST)
    old = []
    for shard in shards:  # as the writer named them before issue 26
        legacy = (tmp_path / shard.uri).with_name("part-00000.parquet")
        (tmp_path / shard.uri).rename(legacy)
        old.append(legacy.relative_to(tmp_path).as_posix())
    (tmp_path / "shards" / "notes.parquet").write_bytes(b"not in a bucket folder: left alone")
    found = legacy_shards(tmp_path)
    assert [f.uri for f in found] == sorted(old)
    assert sorted((f.new_uri, f.sha256) for f in found) == sorted((s.uri, s.sha256) for s in shards)
    for item in found:
        rename_legacy(tmp_path, item)
    assert legacy_shards(tmp_path) == []
    assert sorted(p.relative_to(tmp_path).as_posix() for p in (tmp_path / "shards").rglob("part-*")) == sorted(
        s.uri for s in shards)
    assert (tmp_path / "shards" / "notes.parquet").exists()


def test_a_full_disk_names_the_shard_and_leaves_no_temporary(tmp_path, monkeypatch):
    faults.reset()
    monkeypatch.setenv(faults.ENV, "enospc@shard")
    with pytest.raises(EnvironmentFault, match=r"shards/.*/\.part-00000\.\d+\.tmp: disk full while writing shards$"):
        write_shards(_clips(tmp_path, 3), tmp_path, MANIFEST)
    assert not list((tmp_path / "shards").rglob("*.parquet")) and not list((tmp_path / "shards").rglob(".*"))
    assert remove_stale_temporaries(tmp_path) == []


def test_first_layout_shards_with_map_scores_are_still_read(tmp_path):
    # Shards written before scores became a list of {key, value} (a Parquet map) stay readable.
    clips = _clips(tmp_path, 3)
    shard = write_shards(clips, tmp_path, MANIFEST)[0]
    table = read_shard(tmp_path / shard.uri)
    rows = table.to_pylist()
    old = pa.Table.from_pylist([r | {"scores": sorted(scores_of(r).items())} for r in rows], schema=SHARD_SCHEMA_V1)
    pq.write_table(old, tmp_path / "old.parquet")
    assert pq.read_schema(tmp_path / "old.parquet").field("scores").type == pa.map_(pa.string(), pa.float64())
    assert read_shard(tmp_path / "old.parquet").equals(table)


def test_a_shard_folder_loads_with_hugging_face_datasets(tmp_path):
    datasets = pytest.importorskip("datasets", reason="the dev extra installs datasets")
    clips = _clips(tmp_path)
    shards = write_shards(clips, tmp_path, MANIFEST)
    folder = tmp_path / Path(shards[0].uri).parents[2]  # every bucket of the manifest
    files = sorted(str(p) for p in folder.rglob("*.parquet"))
    assert len(files) == len(shards) > 1
    cache = str(tmp_path / "hf-cache")
    loaded = datasets.load_dataset("parquet", data_dir=str(folder), split="train", cache_dir=cache)
    assert len(loaded) == len(clips)
    assert loaded.features["clip_bytes"] == datasets.Value("binary")
    by_id = {c.clip_id: c for c in clips}
    for row in loaded:
        assert scores_of(row) == by_id[row["clip_id"]].scores
        assert row["clip_bytes"] == (tmp_path / by_id[row["clip_id"]].uri).read_bytes()
    streamed = datasets.load_dataset("parquet", data_files=files, split="train", streaming=True)
    assert sorted(r["clip_id"] for r in streamed) == sorted(by_id)
    narrow = datasets.load_dataset("parquet", data_files=files, split="train", columns=["clip_id", "scores"],
                                   cache_dir=cache)
    assert narrow.column_names == ["clip_id", "scores"] and len(narrow) == len(clips)
