import pytest

from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, ManifestRow, RejectionRecord
from warehouse import audit
from warehouse.store import Warehouse

M = "a" * 64


@pytest.fixture
def chain(tmp_path):
    """manifest -> raw video -> clip -> shard -> checkpoint, plus a second raw video feeding the shard."""
    def art(i, kind):
        return ArtifactRecord(artifact_id=i, kind=kind, uri=f"{kind}/{i}", sha256="1" * 64, manifest_hash=M)
    batch = LineageBatch(
        manifests=[ManifestRow(manifest_hash=M, name="demo", schema_version=1, body="{}")],
        artifacts=[art(M, "manifest"), art("raw1", "raw_video"), art("raw2", "raw_video"), art("clip1", "clip"),
                   art("clip2", "clip"), art("shard1", "shard"), art("ckpt", "checkpoint")],
        edges=[EdgeRecord(parent_id=M, child_id="raw1"), EdgeRecord(parent_id=M, child_id="raw2"),
               EdgeRecord(parent_id="raw1", child_id="clip1"), EdgeRecord(parent_id="raw2", child_id="clip2"),
               EdgeRecord(parent_id="clip1", child_id="shard1"), EdgeRecord(parent_id="clip2", child_id="shard1"),
               EdgeRecord(parent_id="shard1", child_id="ckpt")],
        rejections=[RejectionRecord(artifact_id="clipx", stage="motion", reason="static", manifest_hash=M),
                    RejectionRecord(artifact_id="clipy", stage="motion", reason="static", manifest_hash=M),
                    RejectionRecord(artifact_id="clipz", stage="quality", reason="blur", manifest_hash=M)],
    )
    wh = Warehouse(tmp_path / "w.duckdb")
    wh.write(batch)
    yield wh
    wh.close()


def run(wh, name, **given):
    sql, params = audit.bind(name, given)
    cols, rows = wh.query(sql, params)
    return [dict(zip(cols, r)) for r in rows]


def test_ancestry_walks_back_to_raw_videos_and_manifest(chain):
    rows = run(chain, "ancestry", artifact="ckpt")
    assert {r["artifact_id"] for r in rows} == {"ckpt", "shard1", "clip1", "clip2", "raw1", "raw2", M}
    depth = {r["artifact_id"]: r["depth"] for r in rows}
    assert depth["ckpt"] == 0 and depth["shard1"] == 1 and depth["raw1"] == 3 and depth[M] == 4
    assert all(r["manifest_name"] == "demo" for r in rows)


def test_walk_agrees_with_closure(chain):
    for start in ("ckpt", "shard1", "clip2", "raw1", M):
        assert run(chain, "ancestry_walk", artifact=start) == [
            {k: v for k, v in r.items() if k != "manifest_name"} for r in run(chain, "ancestry", artifact=start)]


def test_rejections_by_stage_and_reason(chain):
    rows = run(chain, "rejections", manifest=M)
    assert [(r["stage"], r["reason"], r["n"]) for r in rows] == [("motion", "static", 2), ("quality", "blur", 1)]


def test_manifest_artifacts(chain):
    rows = run(chain, "manifest_artifacts", manifest=M)
    assert len(rows) == 7 and {r["kind"] for r in rows} >= {"raw_video", "clip", "shard", "checkpoint"}
    assert run(chain, "manifest_artifacts", manifest="b" * 64) == []


def test_injection_is_bound_not_formatted(chain):
    rows = run(chain, "manifest_artifacts", manifest=f"{M}' OR '1'='1")
    assert rows == []
    rows = run(chain, "ancestry", artifact="ckpt'; DROP TABLE edges; --")
    assert rows == []
    assert chain.counts()["edges"] == 7


def test_missing_parameter_and_unknown_audit():
    with pytest.raises(ValueError, match="--artifact"):
        audit.bind("ancestry", {"manifest": M})
    with pytest.raises(audit.UnknownAudit, match="available: .*ancestry"):
        audit.load("nope")


def test_every_audit_names_its_parameters():
    for name in audit.available():
        assert audit.parameters(audit.load(name)), name
        assert audit.describe(name)
