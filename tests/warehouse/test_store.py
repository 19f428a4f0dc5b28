import os
import subprocess
import sys
import time
from pathlib import Path

import duckdb
import pytest

from warehouse.store import SCHEMA_VERSION
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, MetricRecord, RejectionRecord, RunRecord
from warehouse import store
from warehouse.store import Warehouse, WarehouseError

from tests.support import sha256_of


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


class _InterruptedAt:
    """The warehouse's connection, but the call running ``statement`` raises KeyboardInterrupt
    once that statement has run: a signal handled as DuckDB returns (its own signal check, or
    Python's between two bytecodes) surfaces at that call."""

    def __init__(self, con, statement: str):
        self.con, self.statement = con, statement

    def execute(self, sql, *args):
        result = self.con.execute(sql, *args)
        if sql == self.statement:
            self.statement = None
            raise KeyboardInterrupt
        return result

    def __getattr__(self, name):
        return getattr(self.con, name)


@pytest.mark.parametrize("statement", ["BEGIN TRANSACTION", "COMMIT"])
def test_a_signal_at_begin_or_commit_leaves_no_transaction_open(tmp_path, statement):
    """A Ctrl-C or SIGTERM that surfaced at the BEGIN of a batch left its transaction open: the
    run row's close then failed ("cannot start a transaction within a transaction") and the row
    stayed 'running' (an intermittent failure of tests/flows/test_interrupts.py)."""
    with Warehouse(tmp_path / "w.duckdb") as wh:
        wh.start_run(RunRecord(run_id="r1", flow="simulate"))
        con, wh.con = wh.con, _InterruptedAt(wh.con, statement)
        with pytest.raises(KeyboardInterrupt):
            with wh.transaction() as batch:
                batch.execute("INSERT INTO edges VALUES ('p', 'c', 'x')")
        wh.con = con
        wh.finish_run("r1", "failed", "interrupted by SIGINT")
        _, rows = wh.query("SELECT status, message FROM runs")
        edges = wh.counts()["edges"]
    assert rows == [("failed", "interrupted by SIGINT")]
    assert edges == (1 if statement == "COMMIT" else 0)  # a commit that ran stands


FORCED_EXIT = """
import os, sys, threading
from schemas.records import RunRecord
from warehouse.store import Warehouse
wh = Warehouse(sys.argv[1])
wh.start_run(RunRecord(run_id="r1", flow="simulate"))
wh.start_run(RunRecord(run_id="r2", flow="simulate"))
wh.finish_run("r2", "completed")
wh.prepare_forced_finish()
inside = threading.Event()
def interrupted_writer():
    with wh.transaction() as con:  # holds the lock, mid-transaction, as the signal left it
        con.execute("INSERT INTO edges VALUES ('p', 'c', 'x')")
        inside.set()
        threading.Event().wait()
threading.Thread(target=interrupted_writer, daemon=True).start()
inside.wait()
for run_id in ("r1", "r2"):
    wh.finish_run_forced(run_id, "interrupted by SIGTERM")
os._exit(143)
"""


def test_a_forced_exit_closes_its_run_row_while_another_thread_holds_the_warehouse(tmp_path):
    """A thread stopped inside a transaction holds the lock: the forced exit's close goes past it,
    leaves a row already closed as it was, and the half-done transaction is not committed."""
    path = tmp_path / "w.duckdb"
    done = subprocess.run([sys.executable, "-c", FORCED_EXIT, str(path)], cwd=Path(__file__).parents[2],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 143, done.stderr
    with Warehouse(path, read_only=True) as wh:
        _, rows = wh.query("SELECT run_id, status, message, ended_at IS NOT NULL FROM runs ORDER BY run_id")
        edges = wh.counts()["edges"]
    assert rows == [("r1", "failed", "interrupted by SIGTERM", True), ("r2", "completed", None, True)]
    assert edges == 0


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
    con.execute("UPDATE worldline_meta SET value = ? WHERE key = 'schema_version'", [str(SCHEMA_VERSION - 1)])
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


# -- issue 26, point 8: a damaged warehouse is refused before anything is written ----------------
@pytest.fixture(scope="module")
def sound(tmp_path_factory):
    """A warehouse of 20,000 artifacts (a dozen 256 KiB blocks) and the first block of its artifacts' data."""
    path = tmp_path_factory.mktemp("sound") / "w.duckdb"
    with Warehouse(path) as wh:
        wh.write(_batch(20_000, tag="clip"))
    with Warehouse(path, read_only=True) as wh:  # checkpointed at close: the rows are in blocks now
        _, blocks = wh.query("SELECT min(block_id) FROM pragma_storage_info('artifacts') WHERE block_id >= 0")
    return path, blocks[0][0]


def _copy(sound, tmp_path):
    import shutil

    return Path(shutil.copy(sound[0], tmp_path / "w.duckdb"))


def _refused(path: Path, what: str) -> None:
    """Opening ``path`` for writing raises the one-line damage error, and writes nothing."""
    from schemas.errors import EXIT_ENVIRONMENT, EnvironmentFault

    before = {p.name: sha256_of(p) for p in path.parent.iterdir()}
    with pytest.raises(EnvironmentFault) as caught:
        Warehouse(path, lock_timeout=0)
    message = str(caught.value)
    assert message.startswith(f"{path}: the warehouse is damaged (") and what in message, message
    assert "move" in message and "\n" not in message and caught.value.exit_code == EXIT_ENVIRONMENT
    assert {p.name: sha256_of(p) for p in path.parent.iterdir()} == before


def test_a_sound_copy_opens(sound, tmp_path):
    with Warehouse(_copy(sound, tmp_path), lock_timeout=0) as wh:
        assert wh.counts()["artifacts"] == 20_000


def test_a_truncated_warehouse_is_refused(sound, tmp_path):
    path = _copy(sound, tmp_path)
    os.truncate(path, path.stat().st_size // 2)
    _refused(path, "Could not read enough bytes")


def test_a_flipped_byte_in_a_data_block_is_refused_and_named_by_a_reader_too(sound, tmp_path):
    from schemas.errors import EnvironmentFault

    path = _copy(sound, tmp_path)
    with open(path, "r+b") as f:  # a block is 8 bytes of checksum, then data (DuckDB's storage format)
        f.seek(store_header_bytes() + sound[1] * 262_144 + 8 + 100)
        byte = f.read(1)
        f.seek(-1, os.SEEK_CUR)
        f.write(bytes([byte[0] ^ 0x01]))
    _refused(path, "Corrupt database file")
    with Warehouse(path, read_only=True, lock_timeout=0) as wh:  # readers are not checked up front
        with pytest.raises(EnvironmentFault, match="the warehouse is damaged"):
            wh.query("SELECT * FROM artifacts")


def test_a_wal_duckdb_cannot_replay_is_refused_and_left_in_place(sound, tmp_path):
    path = _copy(sound, tmp_path)
    (tmp_path / "w.duckdb.wal").write_bytes(np_random_bytes(5000))
    _refused(path, "w.duckdb.wal beside it is a write-ahead log DuckDB cannot replay")


def test_a_wal_left_by_a_killed_writer_is_replayed(sound, tmp_path):
    path = _copy(sound, tmp_path)
    writer = ("import duckdb, os, sys\n"
              "con = duckdb.connect(sys.argv[1])\n"
              "con.execute(\"SET checkpoint_threshold = '10GB'\")\n"
              "con.execute(\"INSERT INTO artifacts (artifact_id, kind) VALUES ('late', 'clip')\")\n"
              "os._exit(0)\n")  # killed: the row is only in the write-ahead log
    subprocess.run([sys.executable, "-c", writer, str(path)], check=True)
    assert (tmp_path / "w.duckdb.wal").stat().st_size > 0
    with Warehouse(path, lock_timeout=0) as wh:
        assert wh.query("SELECT count(*) FROM artifacts WHERE artifact_id = 'late'")[1] == [(1,)]
    assert not (tmp_path / "w.duckdb.wal").exists()


def test_a_file_that_is_not_duckdb_is_damaged(tmp_path):
    path = tmp_path / "w.duckdb"
    path.write_bytes(np_random_bytes(300_000))
    _refused(path, "")


# -- issue 26, point 6: a warehouse another process holds is waited for, then Busy ---------------
# Issue 30: a reader holding the file read-only (the duckdb CLI with -readonly) holds up a writer
# the same way; readers that should not read the snapshot (warehouse/snapshot.py).
HOLD_DUCKDB = ("import duckdb, sys, time\ncon = duckdb.connect(sys.argv[1], read_only=sys.argv[3] == 'ro')\n"
               "print('held', flush=True)\ntime.sleep(float(sys.argv[2]))\n")
HOLDERS = pytest.mark.parametrize("mode", ["rw", "ro"], ids=["a writer", "a reader"])


def _hold(path: Path, seconds: float, mode: str) -> subprocess.Popen:
    holder = subprocess.Popen([sys.executable, "-c", HOLD_DUCKDB, str(path), str(seconds), mode], stdout=subprocess.PIPE,
                              text=True)
    assert holder.stdout.readline().strip() == "held"
    return holder


@HOLDERS
def test_a_warehouse_another_process_holds_is_busy_after_the_timeout(tmp_path, mode):
    from schemas.errors import Busy

    path = tmp_path / "w.duckdb"
    Warehouse(path).close()
    holder = _hold(path, 30, mode)
    try:
        t0 = time.monotonic()
        with pytest.raises(Busy) as caught:
            Warehouse(path, lock_timeout=1)
        waited = time.monotonic() - t0
    finally:
        holder.kill()
        holder.wait()
    assert 1 <= waited < 5
    assert str(caught.value) == (f"{path}: another process (pid {holder.pid}) has the warehouse open; "
                                 "waited 1 s (WORLDLINE_LOCK_TIMEOUT)")


@HOLDERS
def test_a_warehouse_released_within_the_timeout_opens(tmp_path, mode):
    path = tmp_path / "w.duckdb"
    Warehouse(path).close()
    holder = _hold(path, 1.5, mode)
    t0 = time.monotonic()
    with Warehouse(path, lock_timeout=30) as wh:
        waited = time.monotonic() - t0
        assert wh.counts()["runs"] == 0
    holder.wait()
    assert 0.5 < waited < 15, waited  # it waited (with backoff), then opened


def store_header_bytes() -> int:
    return 3 * 4096  # DuckDB's main header and two database headers precede block 0


def np_random_bytes(n: int) -> bytes:
    import numpy as np

    return np.random.default_rng(26).integers(0, 256, n, dtype=np.uint8).tobytes()
