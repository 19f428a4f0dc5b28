"""The lineage writer: one process, batched transactions, idempotent inserts.

A warehouse opened for writing is checked first (issue 26): DuckDB verifies a block's checksum
when it reads the block, so every table is read once (a flipped byte in data, or a truncated
file, fails there), and a write-ahead log left beside the file must be one DuckDB replays
(it silently ignores one it cannot: garbage, or another database's). A damaged warehouse
raises EnvironmentFault before anything is written; a warehouse another process holds is
waited for, up to the lock timeout, then Busy.

Readers do not hold up the writer (issue 30): the writer publishes a read snapshot beside the
file (warehouse/snapshot.py) and a reader opens it instead of the main file whenever it is
current or a writer holds the main file.
"""

from __future__ import annotations

import json
import re
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, nullcontext, suppress
from importlib import resources
from pathlib import Path
from typing import Any

import duckdb
import pyarrow as pa

from schemas.errors import Busy, EnvironmentFault, NotBuilt
from schemas.records import LineageBatch, Record, RunRecord
from warehouse import snapshot

# Column order of each table as the writer fills it; JSON columns are written as text.
# The warehouse file layout's version (not the manifests' schemas.SCHEMA_VERSION): 2 added COMMENT ON text.
SCHEMA_VERSION = 2

COLUMNS: dict[str, tuple[str, ...]] = {
    "manifests": ("manifest_hash", "name", "schema_version", "body", "source_uri", "parent_hash"),
    "stage_runs": ("stage_run_id", "run_id", "stage", "input_key", "manifest_hash", "status",
                   "n_in", "n_out", "seconds", "attrs"),
    "artifacts": ("artifact_id", "kind", "uri", "sha256", "bytes", "manifest_hash", "stage_run_id", "attrs"),
    "edges": ("parent_id", "child_id", "relation"),
    "metrics": ("subject_id", "name", "step", "value", "stage_run_id", "manifest_hash", "attrs"),
    "rejections": ("artifact_id", "stage", "reason", "scores", "detail", "stage_run_id", "manifest_hash"),
}
JSON_COLUMNS = {"attrs", "scores", "params"}
# version -> statements that take a warehouse from version-1 to version. After the last one the
# tables are those of schema.sql, whose COMMENT ON statements are then applied (`comments`).
MIGRATIONS: dict[int, tuple[str, ...]] = {
    2: (),  # issue 30: tables and columns carry COMMENT ON text; nothing else changed
}


# DuckDB's words for a file it cannot trust (a bad block checksum, a short read, a bad header).
_DAMAGE = ("Corrupt database file", "Could not read enough bytes", "not a valid DuckDB database file",
           "Corrupt WAL file", "Failure while replaying WAL")
_LOCKED = "Could not set lock on file"
_OPEN: dict[Path, int] = {}  # connections this process has open, per warehouse file
# Told once when opening the warehouse has to wait for another process (the CLI prints it, as it
# prints the data root lock's wait): "PATH: another process (pid N) has the warehouse open".
on_wait: Callable[[str], None] | None = None


class WarehouseError(RuntimeError):
    pass


class WarehouseMissing(WarehouseError, NotBuilt):
    """No warehouse yet: no flow has run on this data root (exit 3)."""


class WarehouseUnusable(WarehouseError, EnvironmentFault):
    """The warehouse file cannot be used: it cannot be opened (a folder, no permission), is not
    a Worldline warehouse, or has a schema this version cannot read (exit 5, the machine's)."""


def damaged(path: Path, what: str, advice: str = "move it aside (and its .wal) and re-run the flows into a new "
                                                  "file, or restore it from a copy") -> EnvironmentFault:
    return EnvironmentFault(f"{path}: the warehouse is damaged ({what}); {advice}")


def _is_damage(exc: BaseException) -> bool:
    return isinstance(exc, duckdb.Error) and any(words in str(exc) for words in _DAMAGE)


def _first_line(exc: BaseException) -> str:
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def ddl() -> str:
    return resources.files("warehouse").joinpath("schema.sql").read_text()


def comments() -> list[str]:
    """The COMMENT ON statements of schema.sql (every table and column says what it holds)."""
    return re.findall(r"COMMENT ON (?:TABLE|COLUMN) [\w.]+ IS '(?:[^']|'')*';", ddl())


def closure_sql() -> str:
    return resources.files("warehouse").joinpath("closure.sql").read_text()


def _cell(column: str, value: Any) -> Any:
    if column in JSON_COLUMNS:
        return json.dumps(value, sort_keys=True) if value is not None else None
    return value


def _arrow(table: str, rows: list[Record]) -> pa.Table:
    cols = COLUMNS[table]
    data = {c: [_cell(c, getattr(r, c)) for r in rows] for c in cols}
    return pa.table(data)


class Warehouse:
    """Opens (creating or checking the schema version of) a DuckDB lineage file."""

    def __init__(self, path: Path | str, read_only: bool = False, lock_timeout: float | None = None):
        self.source = Path(path)  # the warehouse file
        self.path = self.source  # the file open: a reader's is the snapshot when it reads one
        self.read_only = read_only
        self.snapshot = False  # whether this reader reads the snapshot
        self._publisher = None if read_only else snapshot.publisher(self.path)
        self.before_commit: Callable[[], None] | None = None  # called inside each batch's transaction
        self._spare: duckdb.DuckDBPyConnection | None = None  # for `finish_run_forced`
        if not read_only:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        elif not self.path.exists():
            raise WarehouseMissing(f"{self.path}: no warehouse here yet (run a flow first)")
        if lock_timeout is None:
            from schemas.settings import Settings

            lock_timeout = Settings().lock_timeout
        wal = self.wal_path
        had_wal = wal.is_file() and wal.stat().st_size > 0
        self._key = self.path.resolve()
        first = not _OPEN.get(self._key)  # a nested flow's open shares the checked database DuckDB has loaded
        self.con = self._open_reader(lock_timeout) if read_only else self._connect(self.path, lock_timeout)
        self._key = self.path.resolve()
        _OPEN[self._key] = _OPEN.get(self._key, 0) + 1
        self._lock = threading.Lock()
        try:
            if not read_only and first:
                self._check_intact(had_wal)
            self._check_version()
            if not read_only and not snapshot.is_current(self.path):  # new, migrated, or a run died
                self.publish_snapshot()
        except BaseException:
            self.close()
            raise

    @property
    def wal_path(self) -> Path:
        return self.path.with_name(self.path.name + ".wal")

    def _connect(self, path: Path, timeout: float) -> duckdb.DuckDBPyConnection:
        """Connect, waiting (with backoff) while another process holds the file: DuckDB takes an
        OS lock per process, and a worldline writer holds the data root's lock too, so this
        waits for a process outside worldline's lock (or a reader of the main file) to let go."""
        deadline, pause, told = time.monotonic() + timeout, 0.05, False
        while True:
            try:
                return duckdb.connect(str(path), read_only=self.read_only)
            except duckdb.Error as exc:
                if _is_damage(exc):
                    raise damaged(path, _first_line(exc)) from None
                if _LOCKED not in str(exc):
                    raise WarehouseUnusable(f"{path}: cannot open the warehouse: {_first_line(exc)}") from exc
                pid = re.search(r"\(PID (\d+)\)", str(exc))
                holder = f"{path}: another process{f' (pid {pid[1]})' if pid else ''} has the warehouse open"
                if time.monotonic() >= deadline:
                    raise Busy(f"{holder}; waited {timeout:g} s (WORLDLINE_LOCK_TIMEOUT)") from None
                if on_wait is not None and not told:
                    on_wait(holder)
                    told = True
            time.sleep(min(pause, max(0.0, deadline - time.monotonic())))
            pause = min(pause * 2, 1.0)

    def _open_reader(self, timeout: float) -> duckdb.DuckDBPyConnection:
        """The snapshot when it is current or this process writes the main file; else the main
        file if no process holds it; else (a writer holds it) the snapshot, a few seconds behind;
        with no snapshot at all, the main file waited for as before."""
        snap = snapshot.snapshot_path(self.source)
        here = bool(_OPEN.get(self.source.resolve()))  # this process writes it: DuckDB refuses a read-only open too
        if (here or snapshot.is_current(self.source)) and (con := self._open_snapshot(snap)) is not None:
            return con
        try:
            con = self._connect(self.source, 0.0 if snap.is_file() else timeout)
        except Busy:
            if not snap.is_file():
                raise
            return self._open_snapshot(snap) or self._connect(self.source, timeout)
        if snapshot.is_current(self.source) and (snap_con := self._open_snapshot(snap)) is not None:
            con.close()  # a writer closed meanwhile, its last rows published: let the next one in
            return snap_con
        return con

    def _open_snapshot(self, snap: Path) -> duckdb.DuckDBPyConnection | None:
        try:
            con = duckdb.connect(str(snap), read_only=True)
        except duckdb.Error:  # replaced and gone, damaged, held read-write by hand: read the main file
            return None
        self.path, self.snapshot = snap, True
        return con

    def _check_intact(self, had_wal: bool) -> None:
        """Read every block of every table (DuckDB checks each block's checksum as it reads it),
        and refuse a write-ahead log DuckDB did not replay: a checkpoint folds a replayed log
        into the file and removes it, and leaves one it ignored where it was."""
        if had_wal:
            self.con.execute("CHECKPOINT")
            if self.wal_path.is_file() and self.wal_path.stat().st_size > 0:
                raise damaged(self.path, f"{self.wal_path.name} beside it is a write-ahead log DuckDB cannot replay",
                              "move that file aside to open the warehouse without it (what it held is lost), "
                              "or restore both from a copy")
        try:
            for table in self._tables():
                self.con.execute(f'SELECT count(*), bit_xor(hash(COLUMNS(*))) FROM "{table}"').fetchall()
        except duckdb.Error as exc:
            if _is_damage(exc):
                raise damaged(self.path, _first_line(exc)) from None
            raise

    # -- schema -------------------------------------------------------------------------
    def _tables(self) -> set[str]:
        rows = self.con.execute("SELECT table_name FROM information_schema.tables WHERE table_schema = 'main'").fetchall()
        return {r[0] for r in rows}

    def _check_version(self) -> None:
        tables = self._tables()
        if "worldline_meta" not in tables:
            if tables:
                raise WarehouseUnusable(f"{self.path}: not a Worldline warehouse (tables {sorted(tables)[:5]} but no worldline_meta)")
            if self.read_only:
                raise WarehouseUnusable(f"{self.path}: empty database, not a Worldline warehouse")
            self.con.execute(ddl())
            self.con.execute("INSERT INTO worldline_meta VALUES ('schema_version', ?)", [str(SCHEMA_VERSION)])
            return
        row = self.con.execute("SELECT value FROM worldline_meta WHERE key = 'schema_version'").fetchall()
        version = int(row[0][0]) if row else 0
        if version > SCHEMA_VERSION:
            raise WarehouseUnusable(
                f"{self.path}: schema version {version} was written by a newer Worldline "
                f"(this one knows {SCHEMA_VERSION}); refusing to mix them")
        if version < SCHEMA_VERSION:
            missing = [v for v in range(version + 1, SCHEMA_VERSION + 1) if v not in MIGRATIONS]
            if missing or self.read_only:
                raise WarehouseUnusable(
                    f"{self.path}: schema version {version} is older than {SCHEMA_VERSION} and "
                    f"{'cannot be migrated read-only' if self.read_only else 'has no migration'}; "
                    "move it aside or re-run the flows into a new file")
            with self.transaction():
                for v in range(version + 1, SCHEMA_VERSION + 1):
                    for stmt in MIGRATIONS[v]:
                        self.con.execute(stmt)
                for stmt in comments():
                    self.con.execute(stmt)
                self.con.execute("UPDATE worldline_meta SET value = ? WHERE key = 'schema_version'", [str(SCHEMA_VERSION)])

    # -- writing ------------------------------------------------------------------------
    @contextmanager
    def transaction(self) -> Iterator[duckdb.DuckDBPyConnection]:
        """One transaction; after it commits, the read snapshot is published when the throttle
        allows, else once it does. Every writer of this file in this process holds the file's
        publish lock meanwhile, so no commit lands while a publish copies the file."""
        publisher = self._publisher
        with self._lock, publisher.lock if publisher else nullcontext(), self._damage_named():
            # BEGIN and COMMIT inside the try: a Ctrl-C or SIGTERM surfaces at the call it
            # arrives during or just after, and one at the BEGIN left the transaction open, so
            # the run row's close failed and the row stayed 'running'. A ROLLBACK with nothing
            # to roll back (the BEGIN did not run, or the COMMIT did) is refused, and ignored.
            try:
                self.con.execute("BEGIN TRANSACTION")
                yield self.con
                self.con.execute("COMMIT")
            except BaseException:
                with suppress(duckdb.TransactionException):
                    self.con.execute("ROLLBACK")
                raise
            if publisher is not None:
                publisher.dirty = True
                if publisher.wait_s() == 0:
                    publisher.publish(self.con)
                else:
                    publisher.later(self._publish_due)

    def publish_snapshot(self) -> bool:
        """Publish the read snapshot now (a run's end, the writer's open and close); False when it
        could not (logged) or this is a reader."""
        if self._publisher is None or self.con is None:
            return False
        with self._lock, self._publisher.lock:
            return self._publisher.publish(self.con)

    def _publish_due(self) -> None:
        """The throttle's timer: publish what was committed since the last publish."""
        with self._lock, self._publisher.lock:
            self._publisher.timer = None
            if self.con is not None and self._publisher.dirty:
                self._publisher.publish(self.con)

    def write(self, batch: LineageBatch) -> int:
        """Write a whole batch in one transaction; rows already present are left as they are."""
        written = 0
        with self.transaction() as con:
            for table in COLUMNS:
                rows = getattr(batch, table)
                if not rows:
                    continue
                arrow_rows = _arrow(table, rows)  # noqa: F841 (read by DuckDB's replacement scan)
                cols = ", ".join(COLUMNS[table])
                con.execute(f"INSERT OR IGNORE INTO {table} ({cols}) SELECT {cols} FROM arrow_rows")
                written += len(rows)
            if batch.edges:
                batch_edges = _arrow("edges", batch.edges)  # noqa: F841 (read by closure.sql)
                con.execute(closure_sql())
            if self.before_commit is not None:
                self.before_commit()  # the crash tests' fault point (tasks/faults.py, "lineage")
        return written

    def start_run(self, run: RunRecord) -> None:
        with self.transaction() as con:
            con.execute(
                "INSERT OR IGNORE INTO runs (run_id, flow, manifest_hash, prefect_flow_run_id, status, params) "
                "VALUES (?, ?, ?, ?, ?, ?)",
                [run.run_id, run.flow, run.manifest_hash, run.prefect_flow_run_id, run.status,
                 json.dumps(run.params, sort_keys=True, default=str)])

    def close_interrupted_runs(self, alive: set[str]) -> int:
        """Mark 'running' rows of runs not in ``alive`` as failed; returns how many.

        Only a process holding the file read-write calls this, and DuckDB lets one process
        do that, so a 'running' row that this process did not start belongs to a process that
        died (SIGKILL, power cut) before it could finish its row.
        """
        keep = pa.table({"k": sorted(alive) or [""]})  # noqa: F841
        with self.transaction() as con:
            rows = con.execute("SELECT run_id FROM runs WHERE status = 'running' AND run_id NOT IN (SELECT k FROM keep)").fetchall()
            con.execute("UPDATE runs SET status = 'failed', message = 'interrupted: the process died before the run ended' "
                        "WHERE status = 'running' AND run_id NOT IN (SELECT k FROM keep)")
        return len(rows)

    def finish_run(self, run_id: str, status: str, message: str | None = None) -> None:
        with self.transaction() as con:
            con.execute("UPDATE runs SET status = ?, message = ?, ended_at = current_timestamp WHERE run_id = ?",
                        [status, message, run_id])
        if self._publisher is not None and self._publisher.dirty:  # unless that commit published it
            self.publish_snapshot()  # readers see the run's end at once

    def prepare_forced_finish(self) -> None:
        """Open, now, the second connection `finish_run_forced` writes on."""
        with self._lock:
            if self._spare is None and self.con is not None and not self.read_only:
                self._spare = self.con.cursor()  # DuckDB: a connection of its own to the same database

    def finish_run_forced(self, run_id: str, message: str) -> None:
        """A still 'running' run row closed as failed from a forced exit, on the spare connection and
        without this object's lock: a thread the signal interrupted may hold that lock, or be inside a
        transaction or a checkpoint, for longer than an exit can wait. DuckDB keeps the two
        connections' transactions apart; the commit is in the write-ahead log the next open replays."""
        if self._spare is None:
            raise WarehouseError(f"{self.path}: prepare_forced_finish was not called")
        self._spare.execute("UPDATE runs SET status = 'failed', message = ?, ended_at = current_timestamp "
                            "WHERE run_id = ? AND status = 'running'", [message, run_id])

    def completed_stage_runs(self, stage: str, input_keys: list[str]) -> set[str]:
        """The input keys of this stage that a finished run already covered (the skip marker)."""
        if not input_keys:
            return set()
        keys = pa.table({"k": input_keys})  # noqa: F841
        with self._lock, self._damage_named():  # one connection shared by threads: every use holds the lock
            rows = self.con.execute(
                "SELECT input_key FROM stage_runs WHERE stage = ? AND status IN ('completed', 'partial') "
                "AND input_key IN (SELECT k FROM keys)", [stage]).fetchall()
        return {r[0] for r in rows}

    # -- reading ------------------------------------------------------------------------
    def query(self, sql: str, params: dict[str, Any] | list[Any] | None = None) -> tuple[list[str], list[tuple]]:
        with self._lock, self._damage_named():
            cur = self.con.execute(sql, params or [])
            cols = [d[0] for d in cur.description] if cur.description else []
            return cols, cur.fetchall()

    def query_sandboxed(self, sql: str, params: dict[str, Any] | list[Any] | None = None,
                        limit: int | None = None) -> tuple[list[str], list[tuple], bool]:
        """``query`` for a statement from outside (``worldline sql``), on a reader only: DuckDB's
        file access is off for the rest of this connection first (a read-only connection still
        ran COPY ... TO, EXPORT DATABASE, read_text and glob: `COPY ... TO` the warehouse's own
        path replaced it), and at most ``limit`` rows are fetched (the result streams, so a huge
        one is not held); the third value says whether rows were left unfetched."""
        if not self.read_only:
            raise WarehouseError(f"{self.path}: statements from outside run on a reader only")
        if not sql.strip().strip(";").strip():
            raise WarehouseError("no SQL statement given")
        with self._lock, self._damage_named():
            self.con.execute("SET enable_external_access = false")
            cur = self.con.execute(sql, params or [])
            if cur is None or not cur.description:
                return [], [], False
            rows = cur.fetchall() if limit is None else cur.fetchmany(limit + 1)
            more = limit is not None and len(rows) > limit
            return [d[0] for d in cur.description], rows[:limit] if more else rows, more

    def counts(self) -> dict[str, int]:
        tables = ("runs", *COLUMNS)
        with self._lock, self._damage_named():
            return {t: self.con.execute(f"SELECT count(*) FROM {t}").fetchall()[0][0] for t in tables}

    @contextmanager
    def _damage_named(self) -> Iterator[None]:
        """A damaged block read after the open (a read-only open is not checked up front, and index
        blocks are read only when a lookup needs them) is named in one line."""
        try:
            yield
        except duckdb.Error as exc:
            if _is_damage(exc) and self.snapshot:
                raise damaged(self.path, _first_line(exc), f"delete it: readers then read {self.source.name}, "
                                                           "and the next flow run publishes a new one") from None
            if _is_damage(exc):
                raise damaged(self.path, _first_line(exc)) from None
            raise

    def close(self) -> None:
        """Publish what was committed since the last snapshot, then close the connection and drop
        it: a failed flow run's traceback keeps this object alive until exit, and DuckDB's
        bindings report a connection still referenced then."""
        if self._publisher is not None and self.con is not None:
            with self._lock, self._publisher.lock:
                if self._publisher.dirty:
                    self._publisher.publish(self.con)
                self._publisher.cancel()
        spare, self._spare = self._spare, None
        if spare is not None:
            spare.close()
        con, self.con = self.con, None
        if con is not None:
            con.close()
            _OPEN[self._key] -= 1
            if self._publisher is not None and not _OPEN[self._key]:
                self._publisher.release()  # after DuckDB let go of the file: closing it drops the process's lock

    def __enter__(self) -> "Warehouse":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
