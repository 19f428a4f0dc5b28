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

This module holds the parent's signals and deadline; starting and stopping the server is in
ephemeral_server.py, and the server child itself in ephemeral_child.py.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager

from flows.ephemeral_child import FOLLOW_S, POLL_S, child_main  # noqa: F401  (the server child's entry)
from flows.ephemeral_server import (PARENT_ENV, _GuardedModule, servers_stopped_on_exit,  # noqa: F401
                                    stop_servers)

GRACE_S = 5.0  # from the first signal to a forced exit; the server then takes < 1 s to stop
HOOKS_S = 2.0  # at most this long for the forced exit's hooks


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
    def hooks() -> None:
        for hook in list(before_forced_exit):
            try:
                hook()
            except Exception:  # noqa: BLE001 (nothing may stop the exit)
                pass
        done.set()

    # The hooks (closing the run row) get HOOKS_S, on a thread of their own: one that blocks
    # (the warehouse's connection held by a thread the signal interrupted) must not stop the exit.
    done = threading.Event()
    threading.Thread(target=hooks, daemon=True).start()
    done.wait(HOOKS_S)
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


def leave_after_signal(code: object) -> None:
    """After SIGINT or SIGTERM, once the command has ended (run rows closed, servers stopped, the
    data root's lock released, its exit code set), leave without tearing the interpreter down.
    The pool's worker threads may still be inside a task (MuJoCo, PyAV and DuckDB run native
    code) and the deadline's timer may be about to fire: finalizing under them crashed the
    process (exit -11 instead of 143, once in a CI run). Without a signal this does nothing."""
    if _first_signal is None:
        return
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001 (a closed stream must not stop the exit)
            pass
    os._exit(code if isinstance(code, int) else 128 + _first_signal)


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


if __name__ == "__main__":
    child_main(sys.argv[1:])
