"""Readers beside the writer (issue 30): the read snapshot the writer publishes, and the read API.

DuckDB locks a database file per process: while a flow holds ``lineage.duckdb`` read-write no
other process can open it, even read-only, and a process holding it read-only keeps the next
flow waiting (`Warehouse._connect`, up to WORLDLINE_LOCK_TIMEOUT, then Busy). So the writer
publishes a copy for readers, ``lineage.snapshot.duckdb`` beside it: after a committed write
(at most every `MIN_INTERVAL_S`, or `COST_FACTOR` times what the last copy took, whichever is
longer, the last write of a burst published when that time is up), when a run finishes and
when the writer closes. A publish checkpoints (the file then holds every committed row), copies
the file to ``lineage.snapshot.duckdb.tmp`` while no transaction of this process can run, and
renames the copy over the snapshot. The rename is atomic: a reader that has the old snapshot
open keeps reading the old file, whole, and the next open reads the new one, whole; no reader
ever sees part of a batch, and no reader of the snapshot holds up the writer.

A copy keeps the main file's size and modification time, so a snapshot is *current* when those
still agree and no write-ahead log holds rows it lacks. `Warehouse(read_only=True)` reads the
snapshot when it is current, and when a writer (this process or another) holds the main file
(then it is at most a few seconds behind); otherwise (no snapshot, or rows written since by a
process that died) it reads the main file as before. `query` is what ``worldline sql`` runs.

The copy reads the main file through a descriptor the writer keeps open (`Publisher`): DuckDB's
lock is a POSIX record lock, which the kernel drops when its process closes any descriptor of
the file, so anything in a writer's process that opens and closes ``lineage.duckdb`` lets other
processes in.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import duckdb

if TYPE_CHECKING:
    from warehouse.store import Warehouse

MIN_INTERVAL_S = 2.0  # at most one throttled publish per this many seconds ...
COST_FACTOR = 10.0  # ... or per this many times the last publish's cost, whichever is longer
_FICLONE = 0x40049409  # ioctl: share the blocks of a file (btrfs, XFS); ext4 refuses and the bytes are copied
log = logging.getLogger("worldline.warehouse")


def snapshot_path(warehouse_path: Path | str) -> Path:
    """``lineage.snapshot.duckdb`` beside ``lineage.duckdb``."""
    path = Path(warehouse_path)
    return path.with_name(f"{path.stem}.snapshot{path.suffix}")


def _wal_empty(path: Path) -> bool:
    try:
        return path.with_name(path.name + ".wal").stat().st_size == 0
    except FileNotFoundError:
        return True


def is_current(warehouse_path: Path | str) -> bool:
    """Whether the snapshot holds what the main file holds: a copy keeps the main file's size and
    modification time, a checkpoint changes them, and rows not yet checkpointed are in its log."""
    path = Path(warehouse_path)
    try:
        main, snap = path.stat(), snapshot_path(path).stat()
    except FileNotFoundError:
        return False
    return (main.st_size, main.st_mtime_ns) == (snap.st_size, snap.st_mtime_ns) and _wal_empty(path)


def _copy(src: int, dst: Path) -> None:
    """Copy the file open as ``src`` to ``dst``: its blocks shared where the file system can (an
    instant copy), else its bytes, in the kernel (sendfile reads at an offset, not moving ``src``'s)."""
    size = os.fstat(src).st_size
    with open(dst, "wb") as out:
        try:
            fcntl.ioctl(out.fileno(), _FICLONE, src)
            return
        except OSError:
            pass
        offset = 0
        while offset < size:
            try:
                sent = os.sendfile(out.fileno(), src, offset, size - offset)
            except OSError:  # a system whose sendfile writes only to sockets
                sent = out.write(os.pread(src, min(size - offset, 1 << 22), offset))
            if sent == 0:
                raise OSError(f"the warehouse file shrank while it was copied ({offset} of {size} bytes)")
            offset += sent


def publish(con: duckdb.DuckDBPyConnection, warehouse_path: Path, src: int) -> float:
    """Checkpoint, copy (from ``src``, the file open) and rename; the caller holds the file's
    `Publisher.lock`, so no commit of this process runs meanwhile, and DuckDB lets no other
    process write. Returns its seconds."""
    t0 = time.perf_counter()
    con.execute("CHECKPOINT")
    target = snapshot_path(warehouse_path)
    tmp = target.with_name(target.name + ".tmp")
    try:
        _copy(src, tmp)
        stat = os.fstat(src)
        os.utime(tmp, ns=(stat.st_atime_ns, stat.st_mtime_ns))  # what `is_current` compares
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)  # a full disk leaves no half copy behind
        raise
    return time.perf_counter() - t0


@dataclass
class Publisher:
    """One per warehouse file in a process (every writer `Warehouse` of it shares it): the lock
    every transaction and publish holds, whether rows were committed since the last publish,
    the throttle, and the descriptor the copies read.

    DuckDB's lock on the file is a POSIX record lock, which the kernel drops when the process
    closes *any* descriptor of the file: a copy that opened and closed the file would let other
    processes in while the writer still has it open. So the file is opened once, at the first
    publish, and closed (`release`) only after the last connection of this process to it is.
    """

    path: Path
    lock: threading.RLock = field(default_factory=threading.RLock)
    dirty: bool = False
    last_at: float = float("-inf")  # time.monotonic() of the last publish
    cost: float = 0.0  # seconds the last publish took
    timer: threading.Timer | None = None
    failed: bool = False  # a failure was logged (once)
    fd: int | None = None

    def wait_s(self) -> float:
        """Seconds until a throttled publish may run (0: now)."""
        return max(0.0, self.last_at + max(MIN_INTERVAL_S, COST_FACTOR * self.cost) - time.monotonic())

    def publish(self, con: duckdb.DuckDBPyConnection) -> bool:
        """Publish now (the caller holds ``lock``); a failure is logged, never raised: the writer
        goes on, and readers read the previous snapshot or the main file."""
        self.cancel()
        try:
            if self.fd is None:
                self.fd = os.open(self.path, os.O_RDONLY | os.O_CLOEXEC)
            self.cost = publish(con, self.path, self.fd)
        except (OSError, duckdb.Error) as exc:
            if not self.failed:
                log.warning("%s: could not publish the read snapshot (%s); readers see the previous one",
                            self.path, str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
            self.failed = True
            return False
        self.last_at, self.dirty = time.monotonic(), False
        return True

    def later(self, run: Callable[[], None]) -> None:
        """Call ``run`` once the throttle allows (a burst's last write is published then)."""
        if self.timer is None:
            self.timer = threading.Timer(self.wait_s(), run)
            self.timer.daemon = True
            self.timer.start()

    def release(self) -> None:
        """Close the descriptor (only once this process has no connection to the file left)."""
        fd, self.fd = self.fd, None
        if fd is not None:
            os.close(fd)

    def cancel(self) -> None:
        timer, self.timer = self.timer, None
        if timer is not None and timer is not threading.current_thread():
            timer.cancel()


_PUBLISHERS: dict[Path, Publisher] = {}
_GUARD = threading.Lock()


def publisher(path: Path) -> Publisher:
    key = path.resolve()
    with _GUARD:
        return _PUBLISHERS.setdefault(key, Publisher(key))


# -- the read API ---------------------------------------------------------------------------
def open_snapshot(warehouse_path: Path | str | None = None) -> Warehouse:
    """The warehouse open for reading without holding up a writer: the snapshot when it is
    current or a flow is writing, else the main file (read-only, waited for as any reader)."""
    from warehouse.store import Warehouse

    if warehouse_path is None:
        from schemas.settings import Settings

        warehouse_path = Settings().warehouse_path
    return Warehouse(warehouse_path, read_only=True)


def query(sql: str, params: dict[str, Any] | list[Any] | None = None,
          warehouse_path: Path | str | None = None, limit: int | None = None) -> tuple[list[str], list[tuple], bool]:
    """Column names and rows of one read-only statement (``worldline sql``), at most ``limit``
    rows, and whether more were left; the connection refuses writes, and file access
    (`Warehouse.query_sandboxed`; `WarehouseError` names the statement's error in one line)."""
    from warehouse.store import WarehouseError

    with open_snapshot(warehouse_path) as wh:
        try:
            return wh.query_sandboxed(sql, params, limit)
        except duckdb.Error as exc:
            raise WarehouseError(f"{wh.path}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
