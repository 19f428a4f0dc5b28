import duckdb
import pytest

from schemas import SCHEMA_VERSION
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, MetricRecord, RejectionRecord, RunRecord
from warehouse import store
from warehouse.store import Warehouse, WarehouseError


def _batch(n=3, tag="a"):
    arts = [ArtifactRecord(artifact_id=f"{tag}{i}", kind="clip", uri=f"clips/{tag}{i}.mp4", sha256="0" * 64,
                           bytes=10 + i, manifest_hash="m" * 64, attrs={"i": i}) for i in range(n)]
    edges = [EdgeRecord(parent_id="raw", child_id=a.artifact_id, relation="split_from") for a in arts]
    rej = [RejectionRecord(artifact_id=f"{tag}0", stage="motion", reason="static", scores={"motion": 0.01},
                           manifest_hash="m" * 64)]
    met = [MetricRecord(subject_id=f"{tag}1", name="blur", value=3.5)]
    return LineageBatch(artifacts=arts, edges=edges, rejections=rej, metrics=met)


def test_write_is_idempotent(tmp_path):
    with Warehouse(tmp_path / "w.duckdb") as wh:
        wh.write(_batch())
        wh.write(_batch())
        counts = wh.counts()
    assert counts["artifacts"] == 3 and counts["edges"] == 3 and counts["rejections"] == 1 and counts["metrics"] == 1


def test_json_columns_round_trip(tmp_path):
    with Warehouse(tmp_path / "w.duckdb") as wh:
        wh.write(_batch())
        _, rows = wh.query("SELECT scores->>'$.motion' FROM rejections")
    assert float(rows[0][0]) == 0.01


def test_a_failing_batch_leaves_nothing(tmp_path):
    with Warehouse(tmp_path / "w.duckdb") as wh:
        with pytest.raises(RuntimeError):
            with wh.transaction() as con:
                con.execute("INSERT INTO edges VALUES ('p', 'c', 'x')")
                raise RuntimeError("crash mid-batch")
        assert wh.counts()["edges"] == 0


def test_runs_start_and_finish(tmp_path):
    with Warehouse(tmp_path / "w.duckdb") as wh:
        wh.start_run(RunRecord(run_id="r1", flow="curate", params={"x": 1}))
        wh.finish_run("r1", "partial", "2 inputs failed")
        _, rows = wh.query("SELECT status, message, ended_at IS NOT NULL FROM runs")
    assert rows == [("partial", "2 inputs failed", True)]


def test_newer_schema_is_refused(tmp_path):
    path = tmp_path / "w.duckdb"
    Warehouse(path).close()
    con = duckdb.connect(str(path))
    con.execute("UPDATE worldline_meta SET value = ? WHERE key = 'schema_version'", [str(SCHEMA_VERSION + 1)])
    con.close()
    with pytest.raises(WarehouseError, match="newer Worldline"):
        Warehouse(path)


def test_older_schema_without_migration_is_refused(tmp_path):
    path = tmp_path / "w.duckdb"
    Warehouse(path).close()
    con = duckdb.connect(str(path))
    con.execute("UPDATE worldline_meta SET value = '0' WHERE key = 'schema_version'")
    con.close()
    with pytest.raises(WarehouseError, match="older"):
        Warehouse(path)


def test_older_schema_is_migrated(tmp_path, monkeypatch):
    path = tmp_path / "w.duckdb"
    Warehouse(path).close()
    con = duckdb.connect(str(path))
    con.execute("UPDATE worldline_meta SET value = '0' WHERE key = 'schema_version'")
    con.close()
    monkeypatch.setitem(store.MIGRATIONS, SCHEMA_VERSION, ("ALTER TABLE runs ADD COLUMN migrated BOOLEAN",))
    with Warehouse(path) as wh:
        _, rows = wh.query("SELECT value FROM worldline_meta WHERE key = 'schema_version'")
        cols, _ = wh.query("SELECT * FROM runs")
    assert rows == [(str(SCHEMA_VERSION),)] and "migrated" in cols


def test_foreign_database_is_refused(tmp_path):
    path = tmp_path / "other.duckdb"
    con = duckdb.connect(str(path))
    con.execute("CREATE TABLE t (x INT)")
    con.close()
    with pytest.raises(WarehouseError, match="not a Worldline warehouse"):
        Warehouse(path)


def test_read_only_needs_an_existing_file(tmp_path):
    with pytest.raises(WarehouseError, match="no warehouse"):
        Warehouse(tmp_path / "missing.duckdb", read_only=True)


def test_completed_stage_runs_are_the_skip_marker(tmp_path):
    from schemas.records import StageRunRecord

    with Warehouse(tmp_path / "w.duckdb") as wh:
        wh.write(LineageBatch(stage_runs=[
            StageRunRecord(stage_run_id="s1", run_id="r", stage="decode", input_key="k1"),
            StageRunRecord(stage_run_id="s2", run_id="r", stage="decode", input_key="k2", status="failed"),
        ]))
        assert wh.completed_stage_runs("decode", ["k1", "k2", "k3"]) == {"k1"}
        assert wh.completed_stage_runs("encode", ["k1"]) == set()


def test_close_drops_the_connection_and_may_repeat(tmp_path):
    wh = Warehouse(tmp_path / "w.duckdb")
    wh.close()
    wh.close()  # as __exit__ does after an explicit close
    assert wh.con is None  # nothing of DuckDB's is left for a failed run's traceback to keep alive
