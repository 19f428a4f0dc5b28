"""One writer per data root: an advisory lock (flock) on ``<data_root>/worldline.lock``.

DuckDB lets one process open the warehouse read-write, and Prefect's temporary server migrates
its SQLite database under the data root as it starts: two writers on one data root race on
both (issue 26). A writing command takes this lock before Prefect starts; a flow run's
``recorded_run`` takes it too, for runs a deployment worker starts with no command around them.
It is re-entrant within a process (flock conflicts between two opens of one file, even in one
process) and readers never take it. The kernel drops it when its process dies, SIGKILL
included, so a lock file left behind means nothing.
"""

from __future__ import annotations

import fcntl
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from schemas.errors import Busy, EnvironmentFault

LOCK_FILE = "worldline.lock"

_held: dict[Path, list[int]] = {}  # lock file -> [fd, depth] for the locks this process holds
_guard = threading.Lock()


def holder(path: Path) -> str:
    """What the lock file says about the process holding it ("pid N, command ...")."""
    try:
        text = Path(path).read_text(errors="replace").strip()
    except OSError:
        text = ""
    return text or "pid unknown"


def _command() -> str:
    words = [Path(sys.argv[0]).name, *sys.argv[1:]] if sys.argv and sys.argv[0] else ["python"]
    return " ".join(words)[:200]


def _acquire(root: Path, path: Path, timeout: float, on_wait: Callable[[str], None] | None) -> int:
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    deadline, pause, told = time.monotonic() + timeout, 0.05, False
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except BlockingIOError:
            if time.monotonic() >= deadline:
                os.close(fd)
                raise Busy(f"{root}: another worldline process ({holder(path)}) is writing; "
                           f"waited {timeout:g} s (WORLDLINE_LOCK_TIMEOUT)") from None
            if on_wait is not None and not told:
                on_wait(holder(path))
                told = True
            time.sleep(min(pause, max(0.0, deadline - time.monotonic())))
            pause = min(pause * 2, 1.0)
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"pid {os.getpid()}, command {_command()}\n".encode(), 0)
    return fd


@contextmanager
def writer(data_root: Path | str, timeout: float, on_wait: Callable[[str], None] | None = None) -> Iterator[Path]:
    """Hold the data root's writer lock, waiting up to ``timeout`` seconds for another process
    to release it (``on_wait(holder)`` is called once if it has to wait), else raise Busy."""
    root = Path(data_root)
    try:
        root.mkdir(parents=True, exist_ok=True)
        path = (root / LOCK_FILE).resolve()
        with _guard:  # one thread acquires at a time: a second open of the file would conflict with the first
            if path in _held:
                _held[path][1] += 1
            else:
                _held[path] = [_acquire(root, path, timeout, on_wait), 1]
    except OSError as exc:  # a read-only root, a file where the root belongs, a full disk: the machine's
        where = exc.filename or root
        raise EnvironmentFault(f"{where}: the data root cannot be written ({exc.strerror or exc}); "
                               "WORLDLINE_DATA_ROOT (or --data-root) must name a folder this user can write") from None
    try:
        yield path
    finally:
        with _guard:
            entry = _held[path]
            entry[1] -= 1
            if entry[1] == 0:
                del _held[path]
                os.close(entry[0])  # closing the only descriptor releases the flock


def holds(data_root: Path | str) -> bool:
    """Whether this process holds the data root's writer lock."""
    return (Path(data_root) / LOCK_FILE).resolve() in _held
