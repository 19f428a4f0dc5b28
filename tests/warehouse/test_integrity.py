"""warehouse/integrity.py: the rows a file is checked against, and the rows verify audits."""

from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch
from warehouse import integrity
from warehouse.store import Warehouse


def _warehouse(tmp_path) -> Warehouse:
    wh = Warehouse(tmp_path / "lineage.duckdb")
    wh.write(LineageBatch(artifacts=[
        ArtifactRecord(artifact_id="m" * 64, kind="manifest", uri="m.yaml", sha256="m" * 64, manifest_hash="m" * 64),
        ArtifactRecord(artifact_id="shard1", kind="shard", uri="shards/a.parquet", sha256="1" * 64,
                       manifest_hash="m" * 64),
        ArtifactRecord(artifact_id="shard2", kind="shard", uri="shards/b.parquet", sha256="2" * 64,
                       manifest_hash="m" * 64),
        ArtifactRecord(artifact_id="token1", kind="token_shard", uri="tokens/a.parquet", sha256="3" * 64),
        ArtifactRecord(artifact_id="judged", kind="clip", uri=None, sha256=None, manifest_hash="m" * 64),
        ArtifactRecord(artifact_id="other", kind="clip", uri="shards/a.parquet", sha256="9" * 64,
                       manifest_hash="o" * 64),
    ], edges=[EdgeRecord(parent_id="shard1", child_id="token1", relation="tokens_of")]))
    return wh


def test_claims_recorded_and_parents(tmp_path):
    with _warehouse(tmp_path) as wh:
        by_uri = integrity.claims(wh, "shards/a.parquet", "0" * 64, "shard")
        assert sorted(r[0] for r in by_uri) == ["other", "shard1"]
        copy = integrity.claims(wh, "/elsewhere/b.parquet", "2" * 64, "shard")
        assert [r[0] for r in copy] == ["shard2"] and copy[0][1:] == ("shard", "shards/b.parquet", "2" * 64, "m" * 64)
        assert integrity.claims(wh, "/elsewhere/b.parquet", "2" * 64, "token_shard") == []
        assert set(integrity.recorded(wh, ["shard1", "judged", "nope"])) == {"shard1"}
        assert integrity.recorded(wh, []) == {}
        assert [r[0] for r in integrity.parents(wh, ["token1"], "tokens_of")] == ["shard1"]


def test_files_leave_out_manifests_and_unwritten_artifacts(tmp_path):
    with _warehouse(tmp_path) as wh:
        assert [r[0] for r in integrity.files(wh)] == ["other", "shard1", "shard2", "token1"]
        # a manifest's files, and every row naming one of their paths
        assert [r[0] for r in integrity.files(wh, "m" * 64)] == ["other", "shard1", "shard2"]
        assert integrity.files(wh, "0" * 64) == []
