"""The processes `flows/server.py` starts: each in a session of its own, logging to a file,
stopped by PID (the signal asked for, then SIGTERM, then SIGKILL) along with anything left in
its process group, and dying with this process when the main thread started it."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parents[1]
# A server start takes 10-30 s on this two-core machine when it is busy; keep a wide margin.
START_TIMEOUT_S = 180.0
STOP_TIMEOUT_S = 30.0


class StackError(RuntimeError):
    """A server, worker or deploy step failed; the message names its log file."""


@dataclass
class Child:
    """One process this module started, with the file its output goes to."""

    name: str
    proc: subprocess.Popen
    log: Path

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def tail(self, lines: int = 30) -> str:
        try:
            return "\n".join(self.log.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return ""


def prefect_command(*args: str) -> list[str]:
    """The Prefect CLI of this interpreter (no reliance on PATH)."""
    return [sys.executable, "-m", "prefect", *args]


def spawn(name: str, args: list[str], env: dict[str, str], log: Path) -> Child:
    """Start ``args`` in a session of its own, logging to ``log``. It stops on SIGINT even when
    this process ignores SIGINT (a background job of a script, whose shell starts it so): an
    ignored signal stays ignored across exec, a handled one is reset to its default."""
    log.parent.mkdir(parents=True, exist_ok=True)
    main = threading.current_thread() is threading.main_thread()
    ignored = main and signal.getsignal(signal.SIGINT) == signal.SIG_IGN
    if ignored:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with open(log, "ab") as out:
            proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                                    env=env, cwd=PROJECT_ROOT, start_new_session=True,
                                    preexec_fn=_dies_with(os.getpid()) if main else None)
    finally:
        if ignored:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
    return Child(name, proc, log)


def _dies_with(parent: int):
    """A preexec_fn: the child gets SIGINT (which stops the server and the worker cleanly) when
    this process dies, SIGKILL included, so a killed `worldline server` leaves no worker running
    deployments (issue 26). Linux's PR_SET_PDEATHSIG fires when the *thread* that started the
    child exits, so it is set only for children the main thread starts; a parent already gone
    by the time it is set is caught by the pid check."""
    def arm() -> None:
        if sys.platform.startswith("linux"):
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGINT, 0, 0, 0)  # PR_SET_PDEATHSIG
            if os.getppid() != parent:
                os._exit(1)
    return arm


def died(child: Child) -> StackError:
    return StackError(f"{child.name} (pid {child.pid}) exited with {child.proc.returncode}; "
                      f"see {child.log}:\n{child.tail()}")


def wait_until(ready, child: Child, what: str, timeout: float = START_TIMEOUT_S) -> None:
    """Poll `ready()` twice a second until it is true; fail early if `child` exits meanwhile."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not child.alive():
            raise died(child)
        if ready():
            return
        time.sleep(0.5)
    raise StackError(f"{what} not ready after {timeout:.0f} s; see {child.log}")


def group_members(pgid: int) -> list[int]:
    """Live (not zombie) processes in a process group, read from /proc (Linux)."""
    members = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z" and int(fields[2]) == pgid:
            members.append(int(stat.parent.name))
    return members


def stop(child: Child, first: signal.Signals, timeout: float = STOP_TIMEOUT_S) -> signal.Signals | None:
    """Stop a child by PID: `first`, then SIGTERM, then SIGKILL, waiting `timeout` s after each.

    Returns the signal it stopped on (None if it had already exited). Anything still in its
    process group then gets SIGTERM and SIGKILL. (Flow runs get sessions of their own; a worker
    that stops gracefully kills the ones still running, which is why it gets SIGINT first.)
    """
    stopped_by = None
    for sig in dict.fromkeys((first, signal.SIGTERM, signal.SIGKILL)):
        if not child.alive():
            break
        child.proc.send_signal(sig)
        try:
            child.proc.wait(timeout)
            stopped_by = sig
            break
        except subprocess.TimeoutExpired:
            continue
    for sig in (signal.SIGTERM, signal.SIGKILL):
        if not group_members(child.pid):
            break
        try:
            os.killpg(child.pid, sig)
        except ProcessLookupError:
            break
        deadline = time.monotonic() + 5
        while group_members(child.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
    return stopped_by
