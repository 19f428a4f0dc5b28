"""Issue 30, point 3: readers never break the writer. The writer publishes a read snapshot that
readers open instead of the main file.

The second process is a real one (DuckDB's lock is per process)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import duckdb
import pytest

from warehouse.store import SCHEMA_VERSION
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch
from warehouse import snapshot
from warehouse.store import Warehouse, WarehouseError, WarehouseMissing, comments

from tests.support import REPO

PER_BATCH = 200
BATCHES = 20

# Opens the warehouse as any reader does, prints what it sees (the row of counts of SEE, then
# whether it read the snapshot) and, told to poll, does it again until the stop file exists.
SEE = "SELECT (SELECT count(*) FROM artifacts), (SELECT count(*) FROM edges), (SELECT count(*) FROM ancestry)"
READER = """
import sys, time
from pathlib import Path
from warehouse.store import Warehouse
path, stop, mode, see = sys.argv[1], Path(sys.argv[2]), sys.argv[3], sys.argv[4]
def look(wh):
    print(*wh.query(see)[1][0], int(wh.snapshot), flush=True)
if mode == "hold":
    with Warehouse(path, read_only=True, lock_timeout=0) as wh:
        look(wh)
        while not stop.exists():
            time.sleep(0.02)
        look(wh)
else:
    print("started", flush=True)
    while True:
        last = stop.exists()
        with Warehouse(path, read_only=True, lock_timeout=0) as wh:
            look(wh)
        if last:
            break
"""


def _batch(k: int) -> LineageBatch:
    arts = [ArtifactRecord(artifact_id=f"b{k}c{i}", kind="clip", uri=f"clips/b{k}c{i}.mp4", sha256="0" * 64,
                           bytes=i, manifest_hash="m" * 64) for i in range(PER_BATCH)]
    edges = [EdgeRecord(parent_id=f"b{k}c{i - 1}" if i % 10 else "raw", child_id=a.artifact_id, relation="derived")
             for i, a in enumerate(arts)]  # chains of 10: ancestry rows are written in the batch's transaction too
    return LineageBatch(artifacts=arts, edges=edges)


def reader(path: Path, stop: Path, mode: str, see: str = SEE) -> subprocess.Popen:
    """A process that holds the warehouse open for reading (mode "hold") or opens it again and
    again (mode "poll") until ``stop`` exists; returns once the first has it open."""
    proc = subprocess.Popen([sys.executable, "-c", READER, str(path), str(stop), mode, see], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = proc.stdout.readline().split()
    assert first, proc.stderr.read()
    proc.first = [] if first == ["started"] else [tuple(map(int, first))]
    return proc


def seen(proc: subprocess.Popen) -> list[tuple[int, ...]]:
    """What the reader saw: each look's counts, then 1 when it read the snapshot."""
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    return proc.first + [tuple(map(int, line.split())) for line in out.splitlines()]


@pytest.fixture
def eager(monkeypatch):
    """Publish after every committed write (the throttle is tested on its own)."""
    monkeypatch.setattr(snapshot, "MIN_INTERVAL_S", 0.0)
    monkeypatch.setattr(snapshot, "COST_FACTOR", 0.0)


def test_readers_held_and_polling_never_stop_the_writer_and_see_whole_batches(tmp_path, eager):
    path, stop = tmp_path / "lineage.duckdb", tmp_path / "stop"
    with Warehouse(path, lock_timeout=0) as wh:  # a new warehouse publishes its (empty) snapshot at once
        holder = reader(path, stop, "hold")
        poller = reader(path, stop, "poll")
        for k in range(BATCHES):
            wh.write(_batch(k))
            time.sleep(0.02)
    # The next writer opens at once while the holder has the snapshot open and the poller opens
    # it again and again (a reader that found the main file free as a writer closed holds it for
    # the milliseconds it takes to see the snapshot current, hence not lock_timeout=0), and the
    # holder's view is the file it opened, not the new one.
    t0 = time.monotonic()
    with Warehouse(path, lock_timeout=10) as wh:
        opened = time.monotonic() - t0
        wh.write(_batch(BATCHES))
    stop.touch()
    held, polled = seen(holder), seen(poller)
    with Warehouse(path, read_only=True, lock_timeout=0) as wh:
        final = wh.query("SELECT (SELECT count(*) FROM artifacts), (SELECT count(*) FROM edges), "
                         "(SELECT count(*) FROM ancestry)")[1][0]
        assert wh.snapshot and wh.path == snapshot.snapshot_path(path)

    per_batch = (PER_BATCH, PER_BATCH, final[2] // (BATCHES + 1))
    committed = {tuple(k * n for n in per_batch) for k in range(BATCHES + 2)}
    assert final == tuple((BATCHES + 1) * n for n in per_batch) and final[2] > PER_BATCH
    assert held == [(0, 0, 0, 1)] * 2 and opened < 1.0
    assert set(polled) - {(*c, 1) for c in committed} == set(), "a reader saw part of a batch, or read the main file"
    assert polled == sorted(polled) and polled[-1] == (*final, 1)
    assert len(set(polled)) > 3, polled  # it saw the run progress, not only its two ends


def test_a_snapshot_is_current_after_a_clean_close_and_readers_never_open_the_main_file(tmp_path):
    path = tmp_path / "lineage.duckdb"
    with Warehouse(path) as wh:
        wh.write(_batch(0))
        wh.finish_run("r", "completed")  # a run's end publishes at once
        assert snapshot.is_current(path)
        # The copy did not drop DuckDB's lock (a POSIX lock goes with any close of the file): no
        # other process opens the main file while the writer has it, so readers read the snapshot.
        other = subprocess.run([sys.executable, "-c", "import duckdb, sys; duckdb.connect(sys.argv[1], read_only=True)",
                                str(path)], capture_output=True, text=True)
        assert other.returncode == 1 and "Could not set lock on file" in other.stderr
        wh.write(_batch(1))
        assert not snapshot.is_current(path)  # throttled: published later, or at close
    assert snapshot.is_current(path)
    assert not snapshot.snapshot_path(path).with_name("lineage.snapshot.duckdb.tmp").exists()
    with Warehouse(path, read_only=True) as reader:
        assert reader.snapshot and reader.counts()["artifacts"] == 2 * PER_BATCH
        with Warehouse(path, lock_timeout=0) as writer:  # the main file is free while a reader reads
            writer.write(_batch(2))


def test_the_last_write_of_a_burst_is_published_when_the_throttle_allows(tmp_path, monkeypatch):
    monkeypatch.setattr(snapshot, "MIN_INTERVAL_S", 1.0)
    path = tmp_path / "lineage.duckdb"
    published = []
    real = snapshot.publish
    monkeypatch.setattr(snapshot, "publish", lambda *a: (published.append(time.monotonic()), real(*a))[1])
    with Warehouse(path) as wh:
        for k in range(8):
            wh.write(_batch(k))
        last_write = time.monotonic()
        while not snapshot.is_current(path) and time.monotonic() < last_write + 10:
            time.sleep(0.05)
        settled = len(published)
        con = duckdb.connect(str(snapshot.snapshot_path(path)), read_only=True)
        assert con.execute("SELECT count(*) FROM artifacts").fetchall() == [(8 * PER_BATCH,)]  # with no write since
        con.close()
    assert len(published) == settled  # nothing new to publish at close
    gaps = [b - a for a, b in zip(published, published[1:])]
    assert all(gap >= 0.95 for gap in gaps), gaps  # at most one a second, the last once the second is up


def test_rows_a_killed_writer_left_in_its_log_are_read_from_the_main_file(tmp_path):
    path = tmp_path / "lineage.duckdb"
    with Warehouse(path) as wh:
        wh.write(_batch(0))
    killed = ("import duckdb, os, sys\n"
              "con = duckdb.connect(sys.argv[1])\n"
              "con.execute(\"SET checkpoint_threshold = '10GB'\")\n"
              "con.execute(\"INSERT INTO artifacts (artifact_id, kind) VALUES ('late', 'clip')\")\n"
              "os._exit(0)\n")  # no close: the row is only in the write-ahead log
    subprocess.run([sys.executable, "-c", killed, str(path)], check=True)
    assert not snapshot.is_current(path)
    with Warehouse(path, read_only=True, lock_timeout=0) as wh:
        assert not wh.snapshot and wh.counts()["artifacts"] == PER_BATCH + 1


def test_without_a_snapshot_readers_wait_for_the_main_file_as_before(tmp_path):
    path = tmp_path / "lineage.duckdb"
    with Warehouse(path) as wh:
        wh.write(_batch(0))
    snapshot.snapshot_path(path).unlink()  # a warehouse written before issue 30
    with Warehouse(path, read_only=True, lock_timeout=0) as wh:
        assert not wh.snapshot and wh.path == path and wh.counts()["artifacts"] == PER_BATCH


def test_a_publish_that_fails_never_fails_the_writer(tmp_path, caplog):
    path = tmp_path / "lineage.duckdb"
    (tmp_path / "lineage.snapshot.duckdb.tmp").mkdir()  # where each copy would go: no file can be written
    with Warehouse(path) as wh:
        for k in range(3):
            wh.write(_batch(k))
        wh.finish_run("r", "completed")
    warned = [r.getMessage() for r in caplog.records if "read snapshot" in r.getMessage()]
    assert len(warned) == 1 and warned[0].startswith(f"{path}: could not publish the read snapshot (")  # once
    with Warehouse(path, read_only=True, lock_timeout=0) as wh:  # no snapshot: the main file, as before
        assert not wh.snapshot and wh.counts()["artifacts"] == 3 * PER_BATCH


# A reader holding the main file itself (read-only) makes a writer wait with backoff, then Busy:
# tests/warehouse/test_store.py, the tests of a warehouse another process holds.


# -- the read API (`worldline sql`) ------------------------------------------------------------------
def test_query_reads_the_snapshot_and_refuses_writes(tmp_path, eager):
    path = tmp_path / "lineage.duckdb"
    with pytest.raises(WarehouseMissing, match="no warehouse here yet"):
        snapshot.query("SELECT 1", warehouse_path=path)
    with Warehouse(path) as wh:
        wh.write(_batch(0))
        cols, rows, more = snapshot.query("SELECT kind, count(*) AS n FROM artifacts GROUP BY kind", warehouse_path=path)
        assert cols == ["kind", "n"] and rows == [("clip", PER_BATCH)] and not more  # while the writer holds the main file
        with pytest.raises(WarehouseError) as caught:
            snapshot.query("DELETE FROM artifacts", warehouse_path=path)
        assert "read-only" in str(caught.value) and "\n" not in str(caught.value)
        with pytest.raises(WarehouseError, match="Parser Error"):
            snapshot.query("SELEC 1", warehouse_path=path)
    assert snapshot.query("SELECT count(*) FROM artifacts WHERE bytes < $n", {"n": 10}, path)[1] == [(10,)]


def test_query_neither_writes_nor_reads_files_and_stops_at_its_limit(tmp_path):
    """A hostile user's `worldline sql "COPY (SELECT 1) TO '<the warehouse>'"` replaced the
    warehouse with a CSV file through the read-only connection; read_text printed any file."""
    path = tmp_path / "lineage.duckdb"
    with Warehouse(path) as wh:
        wh.write(_batch(0))
    before = path.read_bytes()
    secret = tmp_path / "secret.txt"
    secret.write_text("not for sql")
    for statement in (f"COPY (SELECT 1 AS x) TO '{path}' (FORMAT csv)", f"COPY artifacts TO '{tmp_path / 'leak.csv'}'",
                      f"EXPORT DATABASE '{tmp_path / 'exported'}'", f"SELECT * FROM read_text('{secret}')",
                      f"SELECT * FROM glob('{tmp_path}/*')"):
        with pytest.raises(WarehouseError) as caught:
            snapshot.query(statement, warehouse_path=path)
        assert "\n" not in str(caught.value), statement
    assert path.read_bytes() == before
    assert not (tmp_path / "leak.csv").exists() and not (tmp_path / "exported").exists()
    for empty in ("", " ; "):
        with pytest.raises(WarehouseError, match="no SQL statement given"):
            snapshot.query(empty, warehouse_path=path)
    cols, rows, more = snapshot.query("SELECT * FROM range(1000000000) t(x)", warehouse_path=path, limit=3)
    assert cols == ["x"] and rows == [(0,), (1,), (2,)] and more  # streamed: a billion rows are not held
    assert snapshot.query("SELECT * FROM range(3) t(x)", warehouse_path=path, limit=3)[2] is False


def test_open_snapshot_follows_the_settings(tmp_path, monkeypatch):
    monkeypatch.setenv("WORLDLINE_DATA_ROOT", str(tmp_path))
    with Warehouse(tmp_path / "lineage.duckdb") as wh:
        wh.write(_batch(0))
    with snapshot.open_snapshot() as wh:
        assert wh.snapshot and wh.path == tmp_path / "lineage.snapshot.duckdb"


# -- COMMENT ON text --------------------------------------------------------------------------------
def _undocumented(path: Path) -> list[str]:
    """Tables and columns of the warehouse without a comment."""
    con = duckdb.connect(str(path), read_only=True)
    try:
        tables = con.execute("SELECT table_name FROM duckdb_tables() WHERE comment IS NULL OR comment = ''").fetchall()
        columns = con.execute("SELECT table_name || '.' || column_name FROM duckdb_columns() "
                              "WHERE NOT internal AND (comment IS NULL OR comment = '')").fetchall()
        n = con.execute("SELECT count(*) FROM duckdb_columns() WHERE NOT internal").fetchall()[0][0]
    finally:
        con.close()
    assert n > 60
    return sorted(r[0] for r in tables + columns)


def test_a_new_warehouse_comments_every_table_and_column(tmp_path):
    path = tmp_path / "lineage.duckdb"
    Warehouse(path).close()
    assert _undocumented(path) == []
    with Warehouse(path, read_only=True) as wh:  # and the snapshot carries them
        assert wh.snapshot
        assert wh.query("SELECT comment FROM duckdb_columns() WHERE table_name = 'runs' AND column_name = 'status'")[1] \
            == [("running, completed, partial (some inputs failed) or failed (interrupted included)",)]


def _version_one(path: Path) -> None:
    """What a warehouse of schema version 1 was: no comments, no snapshot."""
    Warehouse(path).close()
    con = duckdb.connect(str(path))
    for stmt in comments():
        con.execute(stmt.split(" IS ")[0] + " IS NULL")
    con.execute("UPDATE worldline_meta SET value = '1' WHERE key = 'schema_version'")
    con.close()
    snapshot.snapshot_path(path).unlink()


def test_a_version_one_warehouse_is_migrated_to_comments(tmp_path):
    assert SCHEMA_VERSION == 2
    path = tmp_path / "lineage.duckdb"
    _version_one(path)
    assert len(_undocumented(path)) > 60
    with Warehouse(path) as wh:
        wh.write(_batch(0))
        assert wh.query("SELECT value FROM worldline_meta WHERE key = 'schema_version'")[1] == [("2",)]
    assert _undocumented(path) == []
    with Warehouse(path, read_only=True) as wh:
        assert wh.snapshot and wh.counts()["artifacts"] == PER_BATCH


def test_a_version_one_warehouse_read_only_says_it_cannot_be_migrated(tmp_path):
    path = tmp_path / "lineage.duckdb"
    _version_one(path)
    with pytest.raises(WarehouseError) as caught:
        Warehouse(path, read_only=True)
    assert str(caught.value) == (f"{path}: schema version 1 is older than 2 and cannot be migrated read-only; "
                                 "move it aside or re-run the flows into a new file")
    assert not snapshot.snapshot_path(path).exists() and os.listdir(tmp_path) == ["lineage.duckdb"]
