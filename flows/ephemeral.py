"""How a worldline process ends: Ctrl-C, SIGTERM, SIGKILL, and Prefect's temporary server.

A flow called with no PREFECT_API_URL starts Prefect's temporary server (``SubprocessASGIServer``)
as a child in the command's process group. Three things went wrong there (issue 26):

* Ctrl-C reached the server too, it shut down, and the command then spent minutes retrying
  the API to report its flow run crashed. The server now leaves a signal from anyone but its
  parent to its parent: it stops when the parent stops it, when the parent has gone, or 10 s
  after such a signal, whichever comes first.
* A SIGKILLed command left the server running. The server polls its parent pid and stops
  when it changes (PR_SET_PDEATHSIG would fire when the *thread* that started it exits, and
  Prefect starts it from whichever thread first needs the API).
* An interrupted command could take minutes to end (a running task is not interruptible, and
  the thread pool waits for it). The first SIGINT or SIGTERM starts a deadline: after
  ``GRACE_S`` the command stops its servers and exits anyway; a second signal exits at once.
  By then ``recorded_run`` has closed the run row (the signal raises in the flow's thread).

The server child runs as ``python -m flows.ephemeral <uvicorn arguments>``: Prefect's own
``_run_uvicorn_command`` builds the command and environment as always, and only the ``Popen``
its module calls is swapped (``guard_prefect``). A command stops the server it started before
it releases the data root's lock, after sending Prefect's pending logs (Prefect would send them
at exit, to a server already gone).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType

PARENT_ENV = "WORLDLINE_EPHEMERAL_PARENT"
GRACE_S = 5.0  # from the first signal to a forced exit; the server then takes < 1 s to stop
FOLLOW_S = 10.0  # how long the server waits for its parent after a signal from someone else
POLL_S = 0.25


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised as Ctrl-C raises KeyboardInterrupt, so both take one path out."""


def signal_name(exc: BaseException | None = None) -> str | None:
    """SIGINT or SIGTERM when the command got one (whatever ``exc`` it surfaced as: DuckDB, for
    one, turns Ctrl-C during a query into "RuntimeError: Query interrupted"), or when ``exc`` is
    how one surfaces (a run a worker started); else None."""
    if _first_signal is not None:
        return signal.Signals(_first_signal).name
    if isinstance(exc, Terminated) or _is_termination(exc):
        return "SIGTERM"
    return "SIGINT" if isinstance(exc, KeyboardInterrupt) else None


def exit_code(exc: BaseException | None = None) -> int | None:
    """128 + the signal's number (130 after SIGINT, 143 after SIGTERM, the shell's convention),
    or None when there was no signal."""
    name = signal_name(exc)
    return 128 + signal.Signals[name] if name else None


def _is_termination(exc: BaseException) -> bool:
    """Prefect's own SIGTERM bridge, inside a flow run, raises TerminationSignal."""
    exceptions = sys.modules.get("prefect.exceptions")
    return exceptions is not None and isinstance(exc, exceptions.TerminationSignal)


# -- the parent: starting and stopping the server -----------------------------------------------
def _servers():
    module = sys.modules.get("prefect.server.api.server")
    if module is None:  # Prefect never started one
        return []
    return [s for s in list(module.SubprocessASGIServer._instances.values()) if s.server_process is not None]


def stop_servers(started_after: set[int] | None = None, force: bool = False) -> None:
    """Stop the temporary servers this process started (those not in ``started_after``, a set of
    ``id(server)``); ``force`` kills without waiting (the forced exit's path)."""
    servers = [s for s in _servers() if started_after is None or id(s) not in started_after]
    if servers and not force:
        _drain_to_api()
    for server in servers:
        if force:
            try:
                server.server_process.kill()
            except OSError:
                pass
        else:
            server.stop()


def _drain_to_api() -> None:
    """Send the logs and events Prefect still holds while the server can take them (Prefect
    itself drains them at exit, before its atexit hook stops the server; stopping it earlier,
    as a command does, would leave them retrying a closed port for a minute)."""
    from prefect.events.worker import EventsWorker
    from prefect.logging.handlers import APILogWorker

    for service in (APILogWorker, EventsWorker):
        service.drain_all(timeout=2)


@contextmanager
def servers_stopped_on_exit() -> Iterator[None]:
    """Stop, on the way out, the temporary servers started inside this block (a test harness's
    server, started before, is left alone)."""
    before = {id(s) for s in _servers()}
    try:
        yield
    finally:
        stop_servers(started_after=before)


def _guarded(popen_args: list[str], env: dict[str, str] | None) -> tuple[list[str], dict[str, str]]:
    if popen_args[1:3] == ["-m", "uvicorn"]:
        popen_args = [popen_args[0], "-m", __name__, *popen_args[3:]]
    return popen_args, {**(env if env is not None else os.environ), PARENT_ENV: str(os.getpid())}


class _GuardedPopen(subprocess.Popen):
    """Popen as Prefect's server module calls it, running the server under ``child_main``."""

    def __init__(self, args, *rest, **kwargs):
        args, kwargs["env"] = _guarded(list(args), kwargs.get("env"))
        super().__init__(args, *rest, **kwargs)


class _GuardedModule(ModuleType):
    """``subprocess`` as Prefect's server module sees it: the same, but Popen is ``_GuardedPopen``."""

    def __init__(self):
        super().__init__("subprocess")
        self.__dict__.update({k: v for k, v in vars(subprocess).items() if not k.startswith("__")})
        self.Popen = _GuardedPopen


# -- the parent: interrupts ---------------------------------------------------------------------
_first_signal: int | None = None
_redelivery = False  # Prefect's SIGTERM bridge sends the signal it caught once more, to the handler it replaced


# Called by a forced exit before it stops the servers (recording.py closes its run rows here:
# on a busy machine the flow's thread may not have reached them within GRACE_S).
before_forced_exit: list = []


def _force_exit(code: int, why: str) -> None:
    try:
        print(f"worldline: {why}; stopping now", file=sys.stderr, flush=True)
        sys.stdout.flush()
    except Exception:  # noqa: BLE001 (a closed or full stream must not stop the exit)
        pass
    for hook in list(before_forced_exit):
        try:
            hook()
        except Exception:  # noqa: BLE001 (nothing may stop the exit)
            pass
    stop_servers(force=True)
    os._exit(code)


def _arm(signum: int) -> None:
    """The first signal starts the deadline; a second one exits now."""
    global _first_signal
    if _first_signal is not None:
        _force_exit(128 + signum, f"{signal.Signals(signum).name} again")
    _first_signal = signum
    why = f"{signal.Signals(signum).name} {GRACE_S:g} s ago and the command has not ended"
    timer = threading.Timer(GRACE_S, _force_exit, (128 + signum, why))
    timer.daemon = True
    timer.start()


def _on_signal(signum: int, frame) -> None:
    global _redelivery
    if signum == signal.SIGTERM and _redelivery:
        _redelivery = False
    else:
        _arm(signum)
    raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


@contextmanager
def interrupts_handled() -> Iterator[None]:
    """Inside the block SIGINT raises KeyboardInterrupt and SIGTERM Terminated in the main
    thread, and the first of them forces an exit GRACE_S later. A signal ignored on entry (a
    script's background job) stays ignored; the handlers before are put back on the way out."""
    previous = {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM)}
    for signum, handler in previous.items():
        if handler is not signal.SIG_IGN:
            signal.signal(signum, _on_signal)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def guard_prefect() -> None:
    """Before Prefect starts: its temporary servers run under ``child_main``, and the SIGTERM
    handler it installs during a flow run (raising TerminationSignal) starts the deadline too.
    Idempotent."""
    import prefect.utilities.engine as engine
    from prefect.server.api import server as prefect_server

    if not isinstance(prefect_server.subprocess, _GuardedModule):
        prefect_server.subprocess = _GuardedModule()
    bridge = engine._prefect_sigterm_handler
    if getattr(bridge, "arms_deadline", False):
        return

    def _prefect_sigterm_handler(signum: int, *args):
        global _redelivery
        _arm(signum)
        _redelivery = True
        return bridge(signum, *args)

    _prefect_sigterm_handler.arms_deadline = True
    engine._prefect_sigterm_handler = _prefect_sigterm_handler  # Prefect reads it as a module global


# -- the child: the server itself ---------------------------------------------------------------
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


if __name__ == "__main__":
    child_main(sys.argv[1:])
