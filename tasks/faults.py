"""Deterministic crash points for the crash-safety tests (issue 5). Inert unless asked.

``point(name)`` kills the current process with SIGKILL (no cleanup, no ``finally``, no
atexit: what a power cut or the OOM killer does) when ``WORLDLINE_FAULT`` names that point.
``WORLDLINE_FAULT=shard`` kills at the first call of ``point("shard")``; ``shard:3`` at the
third. Points so far: ``decode`` (a video starts decoding), ``clip`` (an encoded clip is
complete in its temporary file), ``shard`` (a shard is complete in its temporary file),
``lineage`` (a batch is inserted but not committed).
"""

from __future__ import annotations

import os
import signal
import threading

ENV = "WORLDLINE_FAULT"
_hits: dict[str, int] = {}
_lock = threading.Lock()


def parse(spec: str | None) -> tuple[str, int] | None:
    """``"shard:3"`` -> ("shard", 3); ``"shard"`` -> ("shard", 1); empty -> None."""
    if not spec:
        return None
    name, _, nth = spec.partition(":")
    return name.strip(), int(nth) if nth else 1


def point(name: str) -> None:
    wanted = parse(os.environ.get(ENV))
    if wanted is None or wanted[0] != name:
        return
    with _lock:
        _hits[name] = _hits.get(name, 0) + 1
        if _hits[name] == wanted[1]:
            os.kill(os.getpid(), signal.SIGKILL)
