"""Issue 26: the rows of an old-layout shard follow it to its name by content."""

from __future__ import annotations

from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch
from warehouse.migrate import rename_shard
from warehouse.store import Warehouse

OLD = "shards/unscoped/lt240p/2-5s/part-00000.parquet"
NEW = "shards/unscoped/lt240p/2-5s/part-00000-bbbbbbbbbbbbbbbb.parquet"


def _shard(artifact_id: str, sha256: str) -> ArtifactRecord:
    return ArtifactRecord(artifact_id=artifact_id, kind="shard", uri=OLD, sha256=sha256)


def test_rows_with_the_files_bytes_follow_it_and_others_stay(tmp_path):
    """Before issue 26 a second run rewrote part-00000: lineage then held the first run's row (a
    sha256 the file no longer had) and the second run's (the file's bytes). Only the second moves."""
    with Warehouse(tmp_path / "lineage.duckdb") as wh:
        wh.write(LineageBatch(
            artifacts=[_shard("first", "a" * 64), _shard("second", "b" * 64),
                       ArtifactRecord(artifact_id="tokens", kind="token_shard", uri="tokens/x/part-00000.parquet",
                                      sha256="c" * 64),
                       ArtifactRecord(artifact_id="other", kind="clip", uri=OLD, sha256="b" * 64)],
            edges=[EdgeRecord(parent_id="second", child_id="tokens", relation="tokenized_from")]))
        assert rename_shard(wh, OLD, NEW, "b" * 64) == 1
        assert rename_shard(wh, OLD, NEW, "b" * 64) == 1  # again (a run killed before the rename): the same
        assert rename_shard(wh, OLD, NEW.replace("bbbb", "dddd"), "d" * 64) == 0  # bytes no row knows
        _, rows = wh.query("SELECT artifact_id, uri FROM artifacts ORDER BY 1")
        _, ancestry = wh.query("SELECT ancestor_id, ancestor_uri FROM ancestry WHERE descendant_id = 'tokens'")
    assert rows == [("first", OLD), ("other", OLD), ("second", NEW), ("tokens", "tokens/x/part-00000.parquet")]
    assert ancestry == [("second", NEW)]
