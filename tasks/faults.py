"""Faults: deterministic crash points for the crash-safety tests (issue 5), injected full
disks (issue 26), and the one rule that turns a full disk into an `EnvironmentFault`.

``point(name)`` is inert unless ``WORLDLINE_FAULT`` names that point. ``WORLDLINE_FAULT=shard``
kills the process with SIGKILL (no cleanup, no ``finally``, no atexit: what a power cut or the
OOM killer does) at the first call of ``point("shard")``; ``shard:3`` at the third.
``enospc@shard`` raises ``OSError(ENOSPC)`` there instead, at that call and every later one
(a full disk stays full); ``enospc@shard:3`` from the third. Points so far: ``decode`` (a video
starts decoding), ``analysis`` (an analysis cache file is complete in its temporary file),
``clip`` (an encoded clip is complete in its temporary file), ``shard`` (a shard is complete in
its temporary file), ``lineage`` (a batch is inserted but not committed).
"""

from __future__ import annotations

import errno
import os
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import NamedTuple

from schemas.errors import EnvironmentFault
from schemas.paths import escaped

ENV = "WORLDLINE_FAULT"
KINDS = ("kill", "enospc")
# The machine's fault, never the input's: no space left, or the user's quota spent.
DISK_FULL = frozenset({errno.ENOSPC, errno.EDQUOT})
_hits: dict[str, int] = {}
_lock = threading.Lock()


class Fault(NamedTuple):
    name: str
    nth: int = 1
    kind: str = "kill"


def parse(spec: str | None) -> Fault | None:
    """``"shard:3"`` -> Fault("shard", 3, "kill"); ``"enospc@shard"`` -> Fault("shard", 1, "enospc"); empty -> None."""
    if not spec:
        return None
    kind, _, rest = spec.rpartition("@")
    name, _, nth = rest.partition(":")
    kind = kind.strip() or "kill"
    if kind not in KINDS:
        raise ValueError(f"{ENV}={spec!r}: unknown fault kind {kind!r} (one of {', '.join(KINDS)})")
    return Fault(name.strip(), int(nth) if nth else 1, kind)


def point(name: str, path: str | os.PathLike | None = None) -> None:
    """A crash point: kills the process, or raises a full disk while writing ``path``, when asked."""
    wanted = parse(os.environ.get(ENV))
    if wanted is None or wanted.name != name:
        return
    with _lock:
        _hits[name] = _hits.get(name, 0) + 1
        hit = _hits[name]
    if wanted.kind == "kill" and hit == wanted.nth:
        os.kill(os.getpid(), signal.SIGKILL)
    if wanted.kind == "enospc" and hit >= wanted.nth:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), *([os.fspath(path)] if path is not None else []))


def reset() -> None:
    """Forget the calls counted so far (tests that inject faults in one process, one after another)."""
    with _lock:
        _hits.clear()


def disk_full(exc: BaseException, path: str | os.PathLike, stage: str) -> EnvironmentFault | None:
    """The one-line `EnvironmentFault` for ``exc`` when it is a full disk, else None."""
    if isinstance(exc, OSError) and exc.errno in DISK_FULL:
        fault = EnvironmentFault(f"{escaped(path)}: disk full while {stage}")
        fault.__cause__ = exc
        return fault
    return None


# The data root's fault, never the input's: a folder that cannot be written, a read-only file
# system, or a file where a folder belongs (mkdir: EEXIST; below it: ENOTDIR) or a folder where a file does.
UNWRITABLE = frozenset({errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOTDIR, errno.EISDIR, errno.EEXIST})


def _inside(name: str | bytes, root: str | os.PathLike) -> bool:
    try:
        return Path(os.fsdecode(name)).resolve().is_relative_to(Path(root).resolve())
    except (OSError, RuntimeError, ValueError):
        return False


def unwritable(exc: BaseException, root: str | os.PathLike, stage: str) -> EnvironmentFault | None:
    """The one-line `EnvironmentFault` for ``exc`` when it is a place under the data root
    ``root`` that cannot be written (so not the input's fault), else None."""
    if not isinstance(exc, OSError) or exc.errno not in UNWRITABLE:
        return None
    name = next((n for n in (exc.filename, exc.filename2) if n is not None and _inside(n, root)), None)
    if name is None:
        return None
    fault = EnvironmentFault(f"{escaped(os.fsdecode(name))}: {exc.strerror or exc} while {stage}; "
                             f"the data root {escaped(os.fspath(root))} must be a folder this user can write")
    fault.__cause__ = exc
    return fault


def machine(exc: BaseException, path: str | os.PathLike, stage: str,
            root: str | os.PathLike) -> EnvironmentFault | None:
    """``disk_full`` or ``unwritable``: the fault when ``exc`` is the machine's, not an input's."""
    return disk_full(exc, path, stage) or unwritable(exc, root, stage)


@contextmanager
def fatal_when_disk_full(path: str | os.PathLike, stage: str, root: str | os.PathLike | None = None) -> Iterator[None]:
    """Re-raise a full disk inside the block as ``EnvironmentFault("PATH: disk full while STAGE")``:
    the run stops, and no input is blamed (quarantined) for what the machine ran out of. Another
    OSError that names no file is given ``path`` as its file; with the data root ``root``, a place
    under it that cannot be written is an `EnvironmentFault` too (``unwritable``)."""
    try:
        yield
    except OSError as exc:
        if (fault := disk_full(exc, path, stage)) is not None:
            raise fault from exc
        named = exc  # PyAV's errors name no file: name the one written
        if exc.filename is None and exc.errno is not None:
            named = OSError(exc.errno, exc.strerror or str(exc), os.fspath(path))
        if root is not None and (fault := unwritable(named, root, stage)) is not None:
            raise fault from exc
        if named is exc:
            raise
        raise named from exc
