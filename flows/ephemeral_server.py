"""Prefect's temporary server as the parent sees it (flows/ephemeral.py): started under
``child_main`` (only the ``Popen`` Prefect's server module calls is swapped), and stopped, after
sending Prefect's pending logs, before the command releases the data root's lock."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType

PARENT_ENV = "WORLDLINE_EPHEMERAL_PARENT"


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
    if popen_args[1:3] == ["-m", "uvicorn"]:  # the server runs flows/ephemeral.py's child_main
        popen_args = [popen_args[0], "-m", "flows.ephemeral", *popen_args[3:]]
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
