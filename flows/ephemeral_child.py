"""Prefect's temporary server itself (run as ``python -m flows.ephemeral``): uvicorn, leaving a
signal from anyone but its parent to its parent. It stops when the parent stops it, when the
parent has gone, or FOLLOW_S after such a signal, whichever comes first."""

from __future__ import annotations

import os
import signal
import threading
import time

from flows.ephemeral_server import PARENT_ENV

FOLLOW_S = 10.0  # how long the server waits for its parent after a signal from someone else
POLL_S = 0.25


def _follow(parent: int, stop) -> None:
    """Stop when the parent has gone, or it asks, or FOLLOW_S after a signal from anyone else."""
    asked_at = None
    while True:
        info = signal.sigtimedwait((signal.SIGINT, signal.SIGTERM), POLL_S)
        if info is not None:
            if info.si_pid == parent and info.si_signo == signal.SIGTERM:
                break
            asked_at = asked_at or time.monotonic()
        if os.getppid() != parent or (asked_at is not None and time.monotonic() - asked_at > FOLLOW_S):
            break
    stop()
    time.sleep(FOLLOW_S)  # uvicorn's shutdown normally ends the process well before this
    os._exit(1)


def child_main(argv: list[str]) -> None:
    """uvicorn with SIGINT and SIGTERM left to ``_follow`` (blocked here, so in every thread
    uvicorn and Prefect start); uvicorn's graceful shutdown is triggered by SIGUSR1."""
    import uvicorn.server
    from uvicorn.main import main as uvicorn_main

    parent = int(os.environ.pop(PARENT_ENV, os.getppid()))
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    uvicorn.server.HANDLED_SIGNALS = (signal.SIGUSR1,)
    threading.Thread(target=_follow, args=(parent, lambda: os.kill(os.getpid(), signal.SIGUSR1)),
                     daemon=True, name="follow-parent").start()
    uvicorn_main.main(args=argv, prog_name="uvicorn")
